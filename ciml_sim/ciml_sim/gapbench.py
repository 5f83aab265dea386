"""`ciml gap-bench`: score the gap diagnosis on scenarios whose effects it is not told.

The answer (each scenario's effects) lives only here and in the scenario files this
module writes for the simulator. Per case, the simulator records training and held-out
motions WITHOUT ground truth into a neutrally named folder (``case_NN/train_K``), and
`ciml diagnose` runs as a separate process on those bag paths alone — nothing of the
scenario can reach it. The result is scored against the answer:

- in-catalogue effects: type right, location (joint/link) right, parameter relative
  error, spurious effects with share > 5 %, held-out shrink;
- out-of-catalogue effects (a term the diagnosis has no candidate for): whether it gave a
  large ``unexplained_share`` localised to the right leg instead of naming a wrong effect
  with confidence.

The suite targets HyQ's joint and link names (the robot the simulator stands in for).
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from collections.abc import Sequence

import numpy as np
import yaml

from ciml_learning.fileio import atomic_write_json, atomic_write_text

NOISE = {"q": 0.0005, "qd": 0.01, "tau": 0.5, "base_orientation": 0.001}
"""The realistic sensor noise of DESIGN §5 (standard deviations)."""

OUT_OF_CATALOGUE = ("joint_stribeck_friction", "joint_spring", "torque_ripple")

TRAIN_MOTIONS: tuple[tuple[str, float], ...] = (("base_only", 12.0), ("walk_35", 16.0), ("trot_35", 8.0))
HELDOUT_MOTIONS: tuple[tuple[str, float], ...] = (("walk_20", 12.0), ("trot_20", 8.0))

SPURIOUS_SHARE = 0.05
UNEXPLAINED_LARGE = 0.5


def _case(effects: list[dict], seed: int, noise: bool = False) -> dict:
    return {"seed": seed, "sensor_noise": dict(NOISE) if noise else {}, "effects": effects}


SUITE: tuple[dict, ...] = (
    # every catalogue effect alone
    _case([{"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0}], 1),
    _case([{"type": "joint_viscous_friction", "joint": "lh_hfe_joint", "value": 4.0}], 2),
    _case([{"type": "actuator_lag", "joints": "all", "time_constant": 0.012}], 3),
    _case([{"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.85}], 4),
    _case([{"type": "torque_offset", "joint": "rh_kfe_joint", "value": 3.0}], 5),
    _case([{"type": "payload", "mass": 6.0, "com": [0.15, 0.0, 0.05]}], 6),
    _case([{"type": "link_mass_scale", "link": "lf_lowerleg", "value": 1.4}], 7),
    _case([{"type": "encoder_offset", "joint": "rf_hfe_joint", "value": 0.02}], 8),
    _case([{"type": "base_imu_tilt", "roll": 0.01, "pitch": -0.005}], 9),
    # other joints, links and magnitudes, with sensor noise
    _case([{"type": "joint_coulomb_friction", "joint": "lh_kfe_joint", "value": 10.0}], 10, noise=True),
    _case([{"type": "joint_viscous_friction", "joint": "rf_hfe_joint", "value": 2.5}], 11, noise=True),
    _case([{"type": "payload", "mass": 10.0, "com": [-0.1, 0.05, 0.0]}], 12, noise=True),
    _case([{"type": "torque_gain", "joint": "lh_kfe_joint", "value": 0.7}], 13, noise=True),
    # combinations of two and three
    _case([{"type": "payload", "mass": 6.0, "com": [0.15, 0.0, 0.05]},
           {"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0}], 14, noise=True),
    _case([{"type": "actuator_lag", "joints": "all", "time_constant": 0.01},
           {"type": "torque_gain", "joint": "rh_hfe_joint", "value": 0.8}], 15),
    _case([{"type": "joint_viscous_friction", "joint": "lf_kfe_joint", "value": 3.0},
           {"type": "torque_offset", "joint": "lh_haa_joint", "value": -4.0}], 16, noise=True),
    _case([{"type": "payload", "mass": 4.0, "com": [0.0, 0.0, 0.05]},
           {"type": "joint_coulomb_friction", "joint": "rh_kfe_joint", "value": 5.0},
           {"type": "actuator_lag", "joints": "all", "time_constant": 0.008}], 17, noise=True),
    _case([{"type": "link_mass_scale", "link": "rh_upperleg", "value": 1.5},
           {"type": "encoder_offset", "joint": "lf_kfe_joint", "value": -0.03},
           {"type": "torque_gain", "joint": "rf_kfe_joint", "value": 1.15}], 18),
    # outside the catalogue: must be reported as unexplained, localised to the right leg
    _case([{"type": "joint_stribeck_friction", "joint": "rf_kfe_joint", "breakaway": 12.0, "coulomb": 4.0,
            "velocity": 0.1}], 19),
    _case([{"type": "joint_spring", "joint": "lh_hfe_joint", "stiffness": 80.0, "rest": 0.0}], 20),
    _case([{"type": "torque_ripple", "joint": "lf_kfe_joint", "amplitude": 6.0, "period": 0.3}], 21),
)


def _location(effect: dict) -> set[str]:
    """The set of joints / links an effect (true or diagnosed) acts on; {'base'} otherwise."""
    for key in ("joint", "joints", "link", "location"):
        if key in effect:
            value = effect[key]
            if value == "all":
                return {"all"}
            return {value} if isinstance(value, str) else set(value)
    return {"base"}


def _main_param(effect: dict) -> dict[str, float]:
    params = effect.get("params", effect)
    return {k: v for k, v in params.items() if k not in ("type", "joint", "joints", "link")}


RELATIVE_TO_ONE = ("torque_gain", "link_mass_scale")
"""Factors whose deviation from 1 is the effect: their error is relative to |value − 1|."""


def _relative_error(truth: dict, found: dict, effect_type: str = "") -> float | None:
    """Largest relative error over the truth's parameters present in `found`."""
    errs = []
    for k, v in truth.items():
        if k not in found:
            continue
        t, f = np.atleast_1d(np.asarray(v, float)), np.atleast_1d(np.asarray(found[k], float))
        if t.shape != f.shape:
            continue
        if effect_type in RELATIVE_TO_ONE and k == "value":
            t, f = t - 1.0, f - 1.0
        scale = np.linalg.norm(t)
        if scale < 1e-9:
            continue
        errs.append(float(np.linalg.norm(f - t) / scale))
    return max(errs) if errs else None


def _leg_of(name: str) -> str:
    return name.split("_")[0]


def score_case(truth_effects: Sequence[dict], diagnosis: dict, all_joints: Sequence[str]) -> dict:
    """Compare a diagnosis.json with the answer of its scenario."""
    found = list(diagnosis.get("effects", []))
    used: set[int] = set()
    rows = []
    for t in truth_effects:
        if t["type"] in OUT_OF_CATALOGUE:
            continue
        t_loc = _location(t)
        candidates = [i for i, f in enumerate(found) if f.get("type") == t["type"]]
        type_ok = bool(candidates)
        if t_loc == {"all"}:
            # an effect on every joint counts when found as "all" or on most joints separately
            where = set().union(*(_location(found[i]) for i in candidates)) if candidates else set()
            hit = "all" in where or len(where & set(all_joints)) >= 0.75 * len(all_joints)
            loc_hits = candidates if hit else []
        else:
            loc_hits = [i for i in candidates if _location(found[i]) & t_loc]
        used.update(loc_hits)
        rel = None
        if loc_hits:
            truth_p = _main_param(t)
            errs = [_relative_error(truth_p, _main_param(found[i]), t["type"]) for i in loc_hits]
            errs = [e for e in errs if e is not None]
            rel = float(np.median(errs)) if errs else None
        rows.append({"type": t["type"], "location": sorted(t_loc), "type_right": type_ok,
                     "location_right": bool(loc_hits), "param_rel_error": rel})
    spurious = [f for i, f in enumerate(found) if i not in used and float(f.get("share", 0.0)) > SPURIOUS_SHARE]
    out = {"effects": rows, "spurious": [{"type": f.get("type"), "location": sorted(_location(f)),
                                          "share": f.get("share")} for f in spurious],
           "shrink_ratio": diagnosis.get("shrink", {}).get("ratio"),
           "unexplained_share": diagnosis.get("unexplained_share")}
    ooc = [t for t in truth_effects if t["type"] in OUT_OF_CATALOGUE]
    if ooc:
        leg = _leg_of(ooc[0]["joint"])
        top = [d["dimension"] for d in diagnosis.get("localization", [])[:3]]
        confident_wrong = [f for f in found if float(f.get("share", 0.0)) > 0.3]
        out["out_of_catalogue"] = {
            "type": ooc[0]["type"], "joint": ooc[0]["joint"],
            "unexplained_large": (diagnosis.get("unexplained_share") or 0.0) >= UNEXPLAINED_LARGE,
            "localised_right": any(leg in d for d in top if not d.startswith("base")),
            "named_wrong_with_confidence": bool(confident_wrong),
            "top_dimensions": top,
            # the out-of-catalogue probe's joint with the largest share (diagnosis.json unexplained_localised)
            "unexplained_joint": max(diagnosis.get("unexplained_localised", []), key=lambda u: u["share"],
                                     default={}).get("joint"),
        }
    return out


def _ciml(*args: str) -> None:
    cmd = [os.path.join(os.path.dirname(sys.executable), "ciml"), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["(no output)"]
        raise RuntimeError(f"{' '.join(cmd[1:3])} failed: {tail[0]}")


def run_case(index: int, spec: dict, out_dir: str, scale: float = 1.0) -> dict:
    """Record the case's motions (no ground truth), diagnose them in a separate process, score."""
    from ciml_learning.robot import load_robot

    case = os.path.join(out_dir, f"case_{index:02d}")
    answer_dir = os.path.join(out_dir, "answers")
    os.makedirs(answer_dir, exist_ok=True)
    scenario_path = os.path.join(answer_dir, f"case_{index:02d}.yaml")
    atomic_write_text(scenario_path, yaml.safe_dump({"name": f"case_{index:02d}", **spec}, sort_keys=False))
    t0 = time.perf_counter()
    bags = {"train": [], "heldout": []}
    for role, motions in (("train", TRAIN_MOTIONS), ("heldout", HELDOUT_MOTIONS)):
        for k, (motion, duration) in enumerate(motions):
            bag = os.path.join(case, f"{role}_{k}")
            if not os.path.isdir(bag):
                _ciml("record", "--scenario", scenario_path, "--motion", motion, "--duration", f"{duration * scale:g}",
                      "--seed", str(100 * spec["seed"] + len(bags[role]) + (50 if role == "heldout" else 0)),
                      "--no-ground-truth", "--out", bag)
            bags[role].append(bag)
    t1 = time.perf_counter()
    diag_dir = os.path.join(case, "diagnosis")
    _ciml("diagnose", "--bag", *bags["train"], "--heldout", *bags["heldout"], "--out", diag_dir)
    t2 = time.perf_counter()
    with open(os.path.join(diag_dir, "diagnosis.json"), encoding="utf-8") as f:
        diagnosis = json.load(f)
    scored = score_case(spec["effects"], diagnosis, load_robot().joint_names)
    scored.update({"case": index, "effects_true": spec["effects"], "noise": bool(spec["sensor_noise"]),
                   "record_s": round(t1 - t0, 1), "diagnose_s": round(t2 - t1, 1)})
    return scored


def summarise(cases: list[dict]) -> dict:
    """The issue's targets, measured over the suite."""
    rows = [r for c in cases for r in c.get("effects", [])]
    in_cat = [c for c in cases if "out_of_catalogue" not in c and "error" not in c]
    ooc = [c for c in cases if "out_of_catalogue" in c]
    rel = [r["param_rel_error"] for r in rows if r["param_rel_error"] is not None]
    shrink = [c["shrink_ratio"] for c in in_cat if c.get("shrink_ratio") is not None]
    return {
        "cases": len(cases),
        "failed_cases": sum(1 for c in cases if "error" in c),
        "in_catalogue_effects": len(rows),
        "named_right_fraction": (sum(r["type_right"] and r["location_right"] for r in rows) / len(rows)) if rows else None,
        "cases_with_spurious_effect": sum(1 for c in in_cat if c.get("spurious")),  # in-catalogue cases
        "median_param_rel_error": float(np.median(rel)) if rel else None,
        "median_heldout_shrink": float(np.median(shrink)) if shrink else None,
        "min_heldout_shrink": float(np.min(shrink)) if shrink else None,
        "out_of_catalogue_unexplained_and_localised": sum(
            1 for c in ooc if c["out_of_catalogue"]["unexplained_large"] and c["out_of_catalogue"]["localised_right"]
            and not c["out_of_catalogue"]["named_wrong_with_confidence"]),
        "out_of_catalogue_cases": len(ooc),
        "median_diagnose_s": float(np.median([c["diagnose_s"] for c in cases if "diagnose_s" in c])) if cases else None,
        "targets": {"named_right_fraction": ">= 0.90", "spurious share": "<= 0.05", "median_param_rel_error": "<= 0.15",
                    "median_heldout_shrink": ">= 0.70", "out_of_catalogue_unexplained_and_localised": ">= 2 of 3"},
    }


def table(cases: list[dict]) -> str:
    """Markdown summary table, one row per case."""
    lines = ["| case | true effects | named right | param rel. err | spurious | shrink | unexplained | diagnose [s] |",
             "|---|---|---|---|---|---|---|---|"]
    for c in cases:
        true = "; ".join(f"{e['type']}@{e.get('joint') or e.get('joints') or e.get('link') or 'base'}"
                         for e in c.get("effects_true", []))
        if "error" in c:
            lines.append(f"| {c['case']} | {true} | error: {c['error']} | | | | | |")
            continue
        if "out_of_catalogue" in c:
            o = c["out_of_catalogue"]
            named = f"unexplained: {'yes' if o['unexplained_large'] else 'no'}, leg: {'yes' if o['localised_right'] else 'no'}"
            if o.get("unexplained_joint"):
                named += f", at {o['unexplained_joint']}"
        else:
            named = f"{sum(r['type_right'] and r['location_right'] for r in c['effects'])}/{len(c['effects'])}"
        rel = [r["param_rel_error"] for r in c.get("effects", []) if r["param_rel_error"] is not None]
        fmt = (lambda x: "" if x is None else f"{x:.2f}")
        lines.append(f"| {c['case']} | {true} | {named} | {fmt(max(rel) if rel else None)} | {len(c.get('spurious', []))} "
                     f"| {fmt(c.get('shrink_ratio'))} | {fmt(c.get('unexplained_share'))} | {c.get('diagnose_s', '')} |")
    return "\n".join(lines)


def gap_bench(out_dir: str, cases: Sequence[int] | None = None, jobs: int = 1, scale: float = 1.0,
              progress: bool = True) -> dict:
    """Run the suite (or the given case numbers), write DIR/gap_bench.json and DIR/gap_bench.md."""
    from joblib import Parallel, delayed

    os.makedirs(out_dir, exist_ok=True)
    selected = [i for i in range(1, len(SUITE) + 1) if cases is None or i in cases]

    def one(i: int) -> dict:
        try:
            return run_case(i, SUITE[i - 1], out_dir, scale)
        except Exception as err:  # a failed case is scored as failed, the bench goes on
            return {"case": i, "effects_true": SUITE[i - 1]["effects"], "error": str(err)}

    iterator = selected
    if progress and jobs == 1:
        from tqdm import tqdm

        iterator = tqdm(selected, desc="gap-bench", unit="case")
    results = Parallel(n_jobs=jobs)(delayed(one)(i) for i in iterator)
    results.sort(key=lambda c: c["case"])
    doc = {"summary": summarise(results), "cases": results}
    atomic_write_json(os.path.join(out_dir, "gap_bench.json"), doc)
    atomic_write_text(os.path.join(out_dir, "gap_bench.md"),
                      "# gap-bench\n\n" + table(results) + "\n\n```json\n" + json.dumps(doc["summary"], indent=1) + "\n```\n")
    return doc


def gap_bench_command(args) -> int:
    """`ciml gap-bench --out DIR [--cases N...] [--jobs J] [--scale S]`."""
    from ciml_learning.cliargs import cap_jobs
    from ciml_learning.errors import CimlError
    from ciml_learning.fileio import check_out_dir

    def is_gap_bench_dir(d: str) -> bool:  # a finished or an interrupted gap-bench
        return any(n in ("gap_bench.json", "answers") or n.startswith("case_") for n in os.listdir(d))

    check_out_dir(args.out, is_gap_bench_dir, "gap-bench output")
    if args.cases and any(not 1 <= c <= len(SUITE) for c in args.cases):
        raise CimlError(f"--cases: case numbers are 1 to {len(SUITE)}, got {args.cases}")
    doc = gap_bench(args.out, args.cases, cap_jobs(args.jobs), args.scale)
    print(table(doc["cases"]))
    print(json.dumps(doc["summary"], indent=1))
    print(f"gap-bench: results in {os.path.join(args.out, 'gap_bench.json')} and gap_bench.md")
    return 0
