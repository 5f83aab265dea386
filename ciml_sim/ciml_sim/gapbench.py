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
  with confidence;
- calibration: the fraction of true parameters inside the reported 95 % and 68 % intervals
  (coverage), and whether any estimate outside its physical bounds is reported with confidence;
- honest shrink: the physical shrink (N, Nm, per dimension), the dimensions made worse, the
  noise floor's share of the nominal residual;
- the re-simulated shrink (`ciml verify`, in-catalogue cases): the held-out motions recorded again
  nominal, with the diagnosis' identified_scenario.yaml and with the case's own scenario (the oracle);
- reference cases (``reference_effects``): the simulator records the same motions twice, with the
  reference scenario A and with A + B, and `ciml diagnose --bag A+B... --reference A...` must name
  B, and only B, as what distinguishes them; then the reference motions are recorded again with
  that diagnosis's identified_scenario.yaml (A's identified effects plus B), and a second
  --reference diagnosis against them must find no difference with a share above CLOSURE_SHARE.

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

from ciml_learning.core.fileio import atomic_write_json, atomic_write_text
from ciml_learning.diagnosis.shrink import WORSE_TOLERANCE
from ciml_learning.diagnosis.uncertainty import Z68, Z95
from ciml_learning.effects.draws import REALISTIC_NOISE
from ciml_learning.effects.scenario import TOP_LEVEL

from .scenario import OUT_OF_CATALOGUE_TYPES

NOISE = REALISTIC_NOISE

OUT_OF_CATALOGUE = OUT_OF_CATALOGUE_TYPES

TRAIN_MOTIONS: tuple[tuple[str, float], ...] = (("base_only", 12.0), ("walk_35", 16.0), ("trot_35", 8.0))
HELDOUT_MOTIONS: tuple[tuple[str, float], ...] = (("walk_20", 12.0), ("trot_20", 8.0))

SPURIOUS_SHARE = 0.05
UNEXPLAINED_LARGE = 0.5


def _case(effects: list[dict], seed: int, noise: bool = False, reference: list[dict] | None = None) -> dict:
    """A suite case; with `reference` (scenario A), effects = A + B are the "real" logs and A the reference."""
    out = {"seed": seed, "sensor_noise": dict(NOISE) if noise else {}, "effects": (reference or []) + effects}
    if reference is not None:
        out["reference_effects"] = reference
    return out


def scenario_of(spec: dict, reference: bool = False) -> dict:
    """The scenario mapping (the simulator's input) of a suite case: its real or its reference logs
    (a random case's motions and kind are not the simulator's)."""
    out = {k: v for k, v in spec.items() if k in TOP_LEVEL}
    if reference:
        out["effects"] = spec["reference_effects"]
    return out


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
    # Stribeck friction (in the catalogue since the effect registry; named Coulomb before)
    _case([{"type": "joint_stribeck_friction", "joint": "rf_kfe_joint", "breakaway": 12.0, "coulomb": 4.0,
            "velocity": 0.1}], 19),
    # outside the catalogue: must be reported as unexplained, localised to the right leg
    _case([{"type": "joint_spring", "joint": "lh_hfe_joint", "stiffness": 80.0, "rest": 0.0}], 20),
    _case([{"type": "torque_ripple", "joint": "lf_kfe_joint", "amplitude": 6.0, "period": 0.3}], 21),
    # the torque sensor (not the actuator): its gain and offset in the catalogue, a reading ripple outside it
    _case([{"type": "torque_sensor_gain", "joint": "lh_kfe_joint", "value": 0.8}], 22, noise=True),
    _case([{"type": "torque_sensor_offset", "joint": "rf_haa_joint", "value": -4.0}], 23),
    _case([{"type": "torque_sensor_ripple", "joint": "lf_kfe_joint", "amplitude": 6.0, "period": 2 * np.pi / 10}], 24),
    # sim-to-real against a reference: the reference logs have A, the "real" ones A + B; B must be named
    _case([{"type": "torque_sensor_gain", "joint": "lh_kfe_joint", "value": 0.85}], 25, noise=True,
          reference=[{"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0}]),
    _case([{"type": "link_mass_scale", "link": "lf_lowerleg", "value": 1.5}], 26,
          reference=[{"type": "actuator_lag", "joints": "all", "time_constant": 0.01}]),
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




def _coverage(truth: dict, found: dict) -> dict:
    """Over the true parameters' scalar components that the found effect reports with a standard
    deviation (value ± z·std): how many lie inside the 95 % and 68 % intervals, |error|/std of each
    (the coverage at any level: the random bench's calibration curve), and |error| with the std's
    components (diagnosis.json std_components, where given: which component is too wide or narrow)."""
    params, std = found.get("params", {}), found.get("std", {})
    parts = found.get("std_components", {})
    n95 = n68 = n = 0
    ratios: list[float | None] = []
    errors: list[float] = []
    components: dict[str, list[float]] = {}
    for k, v in truth.items():
        if k not in params or k not in std:
            continue
        t, f, sd = (np.atleast_1d(np.asarray(x, float)) for x in (v, params[k], std[k]))
        if not (t.shape == f.shape == sd.shape):
            continue
        err = np.abs(f - t)
        n95 += int(np.sum(err <= Z95 * sd))
        n68 += int(np.sum(err <= Z68 * sd))
        n += t.size
        ratios += [float(e / s) if s > 0 else (0.0 if e == 0 else None) for e, s in zip(err, sd)]
        errors += err.tolist()
        for name, by_key in parts.items():
            components.setdefault(name, []).extend(np.atleast_1d(np.asarray(by_key[k], float)).tolist())
    out = {"in_95": n95, "in_68": n68, "params": n, "error_over_std": ratios}
    if parts:
        out.update({"abs_error": errors, "std_components": components})
    return out


def confident_outside_bounds(diagnosis: dict) -> list[str]:
    """Effects reported with confidence (high or medium) whose parameter lies outside the physical
    ranges the diagnosis states (diagnosis.json `bounds`)."""
    ranges = diagnosis.get("bounds", {})
    out = []
    for e in diagnosis.get("effects", []):
        if e.get("confidence") not in ("high", "medium"):
            continue
        for k, v in e.get("params", {}).items():
            r = ranges.get(e["type"], {}).get(k)
            if isinstance(r, list) and len(r) == 2 and all(isinstance(x, (int, float)) for x in r):
                vals = np.atleast_1d(np.asarray(v, float))
                if np.any(vals < r[0] - 1e-9) or np.any(vals > r[1] + 1e-9):
                    out.append(f"{e['type']}:{k}={v}")
    return out


def reference_effects_found(diagnosis: dict) -> list[dict]:
    """The differences of a --reference diagnosis (reference_comparison) as effects to score: what it
    names as distinguishing the real logs ("real only", "differs", "reference only")."""
    out = []
    for d in diagnosis.get("reference_comparison", {}).get("differences", []):
        e = {"type": d["type"], "status": d["status"]}
        where = d["where"]
        if where == "all":
            e["joints"] = "all"
        elif where != "base":
            e["link" if where in _LINKS else "joint"] = where
        e["params"] = d.get("params", d.get("params_real", {}))
        e["std"] = d.get("std", {})
        e["share"] = float(d.get("share_real", 1.0)) if d["status"] == "real only" else 1.0
        out.append(e)
    return out


def reference_closure(diagnosis: dict) -> float:
    """The largest share (in the real or the reference logs) of a difference a --reference diagnosis
    still finds; 0 if it finds none. Run against reference logs re-recorded with the first
    diagnosis's identified scenario, it says whether that simulator closes the gap (target ≤ 0.05)."""
    return max((max(float(d.get("share_real", 0.0)), float(d.get("share_reference", 0.0)))
                for d in diagnosis.get("reference_comparison", {}).get("differences", [])), default=0.0)


CLOSURE_SHARE = 0.05
"""A reference case is closed when re-simulating it with the identified scenario leaves no difference
with a larger share (reference_closure)."""


_LINKS: set[str] = set()
"""Link names of the robot (filled from the robot description when scoring)."""


def score_case(truth_effects: Sequence[dict], diagnosis: dict, all_joints: Sequence[str],
               reference_effects: Sequence[dict] | None = None) -> dict:
    """Compare a diagnosis.json with the answer of its scenario. With `reference_effects` (A of a
    reference case), the answer is the rest (B) and the diagnosis' reference_comparison is scored."""
    if reference_effects is not None:
        truth_effects = [t for t in truth_effects if t not in list(reference_effects)]
        found = reference_effects_found(diagnosis)
    else:
        found = list(diagnosis.get("effects", []))
    used: set[int] = set()
    rows = []
    cov = np.zeros(3, int)
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
        row_cov = None
        if loc_hits:
            truth_p = _main_param(t)
            errs = [e for e in (_relative_error(truth_p, _main_param(found[i]), t["type"]) for i in loc_hits)
                    if e is not None]
            rel = float(np.median(errs)) if errs else None
            exact = [i for i in loc_hits if _location(found[i]) == t_loc] or loc_hits[:1]
            row_cov = _coverage(truth_p, found[exact[0]])
            cov += np.asarray([row_cov["in_95"], row_cov["in_68"], row_cov["params"]])
        rows.append({"type": t["type"], "location": sorted(t_loc), "type_right": type_ok,
                     "location_right": bool(loc_hits), "param_rel_error": rel,
                     "coverage": row_cov})
    spurious = [f for i, f in enumerate(found) if i not in used and float(f.get("share", 0.0)) > SPURIOUS_SHARE]
    shr = diagnosis.get("shrink", {})
    out = {"effects": rows, "spurious": [{"type": f.get("type"), "location": sorted(_location(f)),
                                          "share": f.get("share")} for f in spurious],
           "shrink_ratio": shr.get("ratio"),
           "shrink_ratio_physical": shr.get("ratio_physical_per_dimension"),
           # from per_dimension with the diagnosis' own 1 % tolerance (shrink.WORSE_TOLERANCE), for any version
           "worsened_dimensions": [n for n, e in shr.get("per_dimension", {}).items()
                                   if e["rms_with_effects"] > e["rms_nominal"] * (1 + WORSE_TOLERANCE)],
           "noise_floor_share": diagnosis.get("noise_floor", {}).get("share_of_nominal"),
           "unexplained_share": diagnosis.get("unexplained_share"),
           "coverage": {"in_95": int(cov[0]), "in_68": int(cov[1]), "params": int(cov[2])},
           "confident_outside_bounds": confident_outside_bounds(diagnosis),
           "not_identified": [f"{e['type']}@{e.get('joint') or e.get('link') or 'base'}"
                              for e in diagnosis.get("not_identified", [])]}
    if reference_effects is not None:
        out["reference"] = {"named_only_the_difference": bool(rows) and all(r["location_right"] for r in rows)
                            and not spurious,
                            "differences": [f"{f['type']}@{sorted(_location(f))[0]} ({f['status']})" for f in found]}
    ooc = [t for t in truth_effects if t["type"] in OUT_OF_CATALOGUE]
    if ooc:
        leg = _leg_of(ooc[0]["joint"])
        top = [d["dimension"] for d in diagnosis.get("localization", [])[:3]]
        confident_wrong = [f for f in found if float(f.get("share", 0.0)) > 0.3]
        # the out-of-catalogue probe's joint with the largest share (diagnosis.json unexplained_localised)
        probes = diagnosis.get("unexplained_localised", [])
        probe = max(probes, key=lambda u: u["share"]).get("joint") if probes else None
        by_dimension = any(leg in d for d in top if not d.startswith("base"))
        by_probe = probe is not None and _leg_of(probe) == leg
        out["out_of_catalogue"] = {
            "type": ooc[0]["type"], "joint": ooc[0]["joint"],
            "unexplained_large": (diagnosis.get("unexplained_share") or 0.0) >= UNEXPLAINED_LARGE,
            # localised: the leg among the three largest error dimensions, or the unexplained part
            # attributed to a joint of that leg (unexplained_localised)
            "localised_right": by_dimension or by_probe,
            "localised_by_dimension": by_dimension, "localised_by_probe": by_probe,
            "named_wrong_with_confidence": bool(confident_wrong),
            "top_dimensions": top,
            "unexplained_joint": probe,
        }
    return out


def _ciml(*args: str) -> None:
    cmd = [os.path.join(os.path.dirname(sys.executable), "ciml"), *args]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["(no output)"]
        raise RuntimeError(f"{' '.join(cmd[1:3])} failed: {tail[0]}")


def _record_motions(case: str, scenario_path: str, spec: dict, scale: float, prefix: str = "") -> dict[str, list[str]]:
    """Record the training and held-out motions of one scenario into case/<prefix><role>_<k> (no ground
    truth); the seeds depend on the case and the motion only (a reference records the same motions).
    A random case names its own motions (train_motions, heldout_motions: [name, seconds])."""
    bags: dict[str, list[str]] = {"train": [], "heldout": []}
    seed = spec["seed"]
    for role, motions in (("train", spec.get("train_motions", TRAIN_MOTIONS)),
                          ("heldout", spec.get("heldout_motions", HELDOUT_MOTIONS))):
        for k, (motion, duration) in enumerate(motions):
            bag = os.path.join(case, f"{prefix}{role}_{k}")
            if not os.path.isdir(bag):
                _ciml("record", "--scenario", scenario_path, "--motion", motion, "--duration", f"{duration * scale:g}",
                      "--seed", str(100 * seed + len(bags[role]) + (50 if role == "heldout" else 0)),
                      "--no-ground-truth", "--out", bag)
            bags[role].append(bag)
    return bags


def run_case(index: int, spec: dict, out_dir: str, scale: float = 1.0) -> dict:
    """Record the case's motions (no ground truth), diagnose them in a separate process, score.
    A reference case also records the reference scenario's motions and diagnoses with --reference."""
    from ciml_learning.core.robot import load_robot

    robot = load_robot()
    _LINKS.update(robot.link_names)
    case = os.path.join(out_dir, f"case_{index:02d}")
    answer_dir = os.path.join(out_dir, "answers")
    os.makedirs(answer_dir, exist_ok=True)
    scenario_path = os.path.join(answer_dir, f"case_{index:02d}.yaml")
    atomic_write_text(scenario_path,
                      yaml.safe_dump({"name": f"case_{index:02d}", **scenario_of(spec)}, sort_keys=False))
    t0 = time.perf_counter()
    bags = _record_motions(case, scenario_path, spec, scale)
    reference = []
    if "reference_effects" in spec:
        ref_path = os.path.join(answer_dir, f"case_{index:02d}_reference.yaml")
        atomic_write_text(ref_path, yaml.safe_dump({"name": f"case_{index:02d}_reference",
                                                    **scenario_of(spec, reference=True)}, sort_keys=False))
        ref_bags = _record_motions(case, ref_path, spec, scale, prefix="reference_")
        reference = ["--reference", *ref_bags["train"], *ref_bags["heldout"]]
    t1 = time.perf_counter()
    diag_dir = os.path.join(case, "diagnosis")
    # the cases are what runs in parallel (jobs, cluster): each diagnosis reads its bags in its own process
    _ciml("diagnose", "--jobs", "1", "--bag", *bags["train"], "--heldout", *bags["heldout"], *reference,
          "--out", diag_dir)
    t2 = time.perf_counter()
    with open(os.path.join(diag_dir, "diagnosis.json"), encoding="utf-8") as f:
        diagnosis = json.load(f)
    scored = score_case(spec["effects"], diagnosis, robot.joint_names, spec.get("reference_effects"))
    scored.update({"case": index, "effects_true": spec["effects"], "noise": bool(spec["sensor_noise"]),
                   "record_s": round(t1 - t0, 1), "diagnose_s": round(t2 - t1, 1)})
    if _resimulated(spec):
        _ciml("verify", "--real", *bags["heldout"], "--diagnosis", diag_dir, "--oracle", scenario_path,
              "--out", os.path.join(case, "verify"))
        scored.update(resimulated_scores(case))
        scored["verify_s"] = round(time.perf_counter() - t2, 1)
    if "reference_effects" in spec:
        scored["reference_effects"] = spec["reference_effects"]
        # the reference re-recorded with the identified scenario ("the simulator you need"), compared again
        resim = _record_motions(case, os.path.join(diag_dir, "identified_scenario.yaml"), spec, scale,
                                prefix="identified_")
        _ciml("diagnose", "--jobs", "1", "--bag", *bags["train"], "--heldout", *bags["heldout"],
              "--reference", *resim["train"], *resim["heldout"], "--out", os.path.join(case, CLOSURE_DIR))
        scored["reference"].update(closure_scores(case))
        scored["closure_s"] = round(time.perf_counter() - t2, 1)
    return scored


def _resimulated(spec: dict) -> bool:
    """In-catalogue cases without a reference are re-simulated (`ciml verify`)."""
    return "reference_effects" not in spec and not any(e["type"] in OUT_OF_CATALOGUE for e in spec["effects"])


CLOSURE_DIR = "diagnosis_vs_identified"
"""Of a reference case: the --reference diagnosis against the reference re-recorded with the identified scenario."""


def closure_scores(case_dir: str) -> dict:
    """{"closure_max_share": reference_closure} of a reference case's CLOSURE_DIR ({} without one)."""
    path = os.path.join(case_dir, CLOSURE_DIR, "diagnosis.json")
    if not os.path.isfile(path):
        return {}
    with open(path, encoding="utf-8") as f:
        return {"closure_max_share": round(reference_closure(json.load(f)), 4)}


def resimulated_scores(case_dir: str) -> dict:
    """The re-simulated shrink of a case from its case_NN/verify/verify.json ({} without one)."""
    path = os.path.join(case_dir, "verify", "verify.json")
    if not os.path.isfile(path):
        return {}
    with open(path, encoding="utf-8") as f:
        o = json.load(f)["resimulated_shrink"]["overall"]
    return {"resim_shrink": o["shrink"], "resim_shrink_oracle": o.get("shrink_oracle"),
            "resim_gap_nominal": o["gap_nominal"], "resim_gap_identified": o["gap_identified"],
            "resim_gap_oracle": o.get("gap_oracle"), "resim_further_than_nominal": o["further_than_nominal"]}


def summarise(cases: list[dict]) -> dict:
    """The issue's targets, measured over the suite."""
    ok = [c for c in cases if "error" not in c]
    plain = [c for c in ok if "reference" not in c]
    rows = [r for c in plain for r in c.get("effects", [])]
    in_cat = [c for c in plain if "out_of_catalogue" not in c]
    ooc = [c for c in plain if "out_of_catalogue" in c]
    refs = [c for c in ok if "reference" in c]
    rel = [r["param_rel_error"] for r in rows if r["param_rel_error"] is not None]
    shrink = [c["shrink_ratio"] for c in in_cat if c.get("shrink_ratio") is not None]
    phys = [c["shrink_ratio_physical"] for c in in_cat if c.get("shrink_ratio_physical") is not None]
    resim = [c for c in ok if c.get("resim_shrink") is not None]
    of_oracle = [c["resim_shrink"] / c["resim_shrink_oracle"] for c in resim if c.get("resim_shrink_oracle")]
    cov_rows = [[c["coverage"][k] for k in ("in_95", "in_68", "params")] for c in ok if "coverage" in c]
    cov = np.sum(cov_rows, axis=0) if cov_rows else np.zeros(3)
    return {
        "cases": len(cases),
        "failed_cases": sum(1 for c in cases if "error" in c),
        "in_catalogue_effects": len(rows),
        "named_right_fraction": (sum(r["type_right"] and r["location_right"] for r in rows) / len(rows)
                                 if rows else None),
        "cases_with_spurious_effect": sum(1 for c in in_cat if c.get("spurious")),  # in-catalogue cases
        "median_param_rel_error": float(np.median(rel)) if rel else None,
        "coverage_95": float(cov[0] / cov[2]) if cov[2] else None,
        "coverage_68": float(cov[1] / cov[2]) if cov[2] else None,
        "coverage_parameters": int(cov[2]),
        "confident_outside_bounds": sum(len(c.get("confident_outside_bounds", [])) for c in ok),
        "median_heldout_shrink": float(np.median(shrink)) if shrink else None,
        "min_heldout_shrink": float(np.min(shrink)) if shrink else None,
        "median_heldout_shrink_physical": float(np.median(phys)) if phys else None,
        "cases_with_worsened_dimensions": sum(1 for c in in_cat if c.get("worsened_dimensions")),
        "resimulated_cases": len(resim),
        "median_resimulated_shrink": float(np.median([c["resim_shrink"] for c in resim])) if resim else None,
        "median_resimulated_shrink_oracle": (float(np.median([c["resim_shrink_oracle"] for c in resim
                                                              if c.get("resim_shrink_oracle") is not None]))
                                             if of_oracle else None),
        "median_resimulated_shrink_of_oracle": float(np.median(of_oracle)) if of_oracle else None,
        "cases_identified_further_than_nominal": sum(1 for c in resim if c["resim_further_than_nominal"]),
        "out_of_catalogue_unexplained_and_localised": sum(
            1 for c in ooc if c["out_of_catalogue"]["unexplained_large"] and c["out_of_catalogue"]["localised_right"]
            and not c["out_of_catalogue"]["named_wrong_with_confidence"]),
        "out_of_catalogue_cases": len(ooc),
        "reference_cases_named_only_the_difference": sum(1 for c in refs
                                                         if c["reference"]["named_only_the_difference"]),
        "reference_cases": len(refs),
        "reference_cases_closed_by_resimulation": sum(
            1 for c in refs if c["reference"].get("closure_max_share", 1.0) <= CLOSURE_SHARE),
        "median_diagnose_s": float(np.median([c["diagnose_s"] for c in cases if "diagnose_s" in c])) if cases else None,
        "targets": {"named_right_fraction": ">= 0.95", "spurious share": "<= 0.05", "median_param_rel_error": "<= 0.15",
                    "coverage_95": ">= 0.90", "confident_outside_bounds": "0",
                    "median_heldout_shrink": ">= 0.70",
                    "median_resimulated_shrink_of_oracle": ">= 0.90",
                    "cases_identified_further_than_nominal": "0",
                    "out_of_catalogue_unexplained_and_localised": ">= 3 of 4, no catalogue effect above 30 % share",
                    "reference_cases_named_only_the_difference": "all",
                    "reference_cases_closed_by_resimulation": f"all (no difference left above {CLOSURE_SHARE:.0%})"},
    }


def table(cases: list[dict]) -> str:
    """Markdown summary table, one row per case."""
    lines = ["| case | true effects | named right | param rel. err | in 95 % / 68 % interval | spurious | shrink "
             "(normalised / physical) | made worse | noise floor | unexplained | re-simulated shrink / oracle's "
             "| diagnose [s] |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for c in cases:
        ref = {json.dumps(e, sort_keys=True) for e in c.get("reference_effects", [])}

        def name(e: dict) -> str:
            tag = "ref: " if json.dumps(e, sort_keys=True) in ref else ""
            return f"{tag}{e['type']}@{e.get('joint') or e.get('joints') or e.get('link') or 'base'}"

        true = "; ".join(name(e) for e in c.get("effects_true", []))
        if "error" in c:
            lines.append(f"| {c['case']} | {true} | error: {c['error']} | | | | | | | | | |")
            continue
        if "out_of_catalogue" in c:
            o = c["out_of_catalogue"]
            named = (f"unexplained: {'yes' if o['unexplained_large'] else 'no'}, "
                     f"leg: {'yes' if o['localised_right'] else 'no'}")
            if o.get("unexplained_joint"):
                named += f", at {o['unexplained_joint']}"
        else:
            named = f"{sum(r['type_right'] and r['location_right'] for r in c['effects'])}/{len(c['effects'])}"
            if "reference" in c:
                named += " (differences: " + ", ".join(c["reference"]["differences"]) + ")"
        rel = [r["param_rel_error"] for r in c.get("effects", []) if r["param_rel_error"] is not None]

        def fmt(x):
            return "" if x is None else f"{x:.2f}"

        cv = c.get("coverage", {})
        resim = f"{fmt(c.get('resim_shrink'))} / {fmt(c.get('resim_shrink_oracle'))}" if "resim_shrink" in c else ""
        if "closure_max_share" in c.get("reference", {}):
            resim = f"difference left: {c['reference']['closure_max_share']:.1%}"
        cov = f"{cv['in_95']}/{cv['params']} / {cv['in_68']}/{cv['params']}" if cv.get("params") else ""
        lines.append(f"| {c['case']} | {true} | {named} | {fmt(max(rel) if rel else None)} | {cov} "
                     f"| {len(c.get('spurious', []))} "
                     f"| {fmt(c.get('shrink_ratio'))} / {fmt(c.get('shrink_ratio_physical'))} "
                     f"| {', '.join(c.get('worsened_dimensions', []))} | {fmt(c.get('noise_floor_share'))} "
                     f"| {fmt(c.get('unexplained_share'))} "
                     f"| {resim} | {c.get('diagnose_s', '')} |")
    return "\n".join(lines)


def rescore(out_dir: str) -> dict:
    """Score the diagnoses already in DIR again (after a change of the scoring, or of an interrupted
    run: the cases whose case_NN/diagnosis/diagnosis.json exists), without recording or diagnosing;
    rewrites DIR/gap_bench.json and .md."""
    from ciml_learning.core.robot import load_robot

    robot = load_robot()
    _LINKS.update(robot.link_names)
    path = os.path.join(out_dir, "gap_bench.json")
    if os.path.isfile(path):
        with open(path, encoding="utf-8") as f:
            old = {c["case"]: c for c in json.load(f)["cases"]}
    else:
        old = {int(n[5:]): {"case": int(n[5:]), "effects_true": SUITE[int(n[5:]) - 1]["effects"]}
               for n in sorted(os.listdir(out_dir)) if n.startswith("case_") and n[5:].isdigit()
               and 1 <= int(n[5:]) <= len(SUITE)}
    results = []
    for i, c in sorted(old.items()):
        path = os.path.join(out_dir, f"case_{i:02d}", "diagnosis", "diagnosis.json")
        if not os.path.isfile(path):  # not diagnosed (yet): a failed case stays failed
            if "error" in c:
                results.append(c)
            continue
        with open(path, encoding="utf-8") as f:
            diagnosis = json.load(f)
        spec = SUITE[i - 1]
        scored = score_case(spec["effects"], diagnosis, robot.joint_names, spec.get("reference_effects"))
        scored.update({k: c[k] for k in ("case", "effects_true", "noise", "record_s", "diagnose_s") if k in c})
        scored.setdefault("diagnose_s", diagnosis.get("time_s"))
        scored.update(resimulated_scores(os.path.join(out_dir, f"case_{i:02d}")))
        if "reference_effects" in spec:
            scored["reference_effects"] = spec["reference_effects"]
            scored["reference"].update(closure_scores(os.path.join(out_dir, f"case_{i:02d}")))
        results.append(scored)
    return _write(out_dir, results)


def _write(out_dir: str, results: list[dict]) -> dict:
    doc = {"summary": summarise(results), "cases": results}
    atomic_write_json(os.path.join(out_dir, "gap_bench.json"), doc)
    atomic_write_text(os.path.join(out_dir, "gap_bench.md"),
                      "# gap-bench\n\n" + table(results) + "\n\n```json\n" + json.dumps(doc["summary"], indent=1)
                      + "\n```\n")
    return doc


def suite_case(job: tuple[int, str, float]) -> dict:
    """Run suite case (number, out_dir, scale) here (a joblib or a Dask worker)."""
    i, out_dir, scale = job
    try:
        return run_case(i, SUITE[i - 1], out_dir, scale)
    except Exception as err:  # a failed case is scored as failed, the bench goes on
        return {"case": i, "effects_true": SUITE[i - 1]["effects"], "error": str(err)}


def gap_bench(out_dir: str, cases: Sequence[int] | None = None, jobs: int = 1, scale: float = 1.0,
              progress: bool = True, cluster: str | None = None) -> dict:
    """Run the suite (or the given case numbers) with joblib or on a Dask `cluster`
    (ciml_learning.learning.cluster), write DIR/gap_bench.json and DIR/gap_bench.md."""
    from ciml_learning.learning.cluster import run_all

    os.makedirs(out_dir, exist_ok=True)
    selected = [(i, os.path.abspath(out_dir), scale) for i in range(1, len(SUITE) + 1) if cases is None or i in cases]
    iterator: Sequence = selected
    if progress and jobs == 1 and cluster is None:
        from tqdm import tqdm

        iterator = tqdm(selected, desc="gap-bench", unit="case")
    results = run_all(suite_case, iterator, jobs, cluster, module="ciml_sim.gapbench")
    results.sort(key=lambda c: c["case"])
    return _write(out_dir, results)


def is_gap_bench_dir(d: str) -> bool:
    """A finished or an interrupted gap-bench (the suite's or a random one): ours to replace."""
    return any(n in ("gap_bench.json", "answers") or n.startswith("case_") for n in os.listdir(d))


def gap_bench_command(args) -> int:
    """`ciml gap-bench --out DIR [--cases N...] [--jobs J | --cluster ADDRESS] [--scale S]` (the suite;
    gaprandom.command sends --random here or to the random bench)."""
    from ciml_learning.cli.args import cap_jobs
    from ciml_learning.core.errors import CimlError
    from ciml_learning.core.fileio import check_out_dir

    check_out_dir(args.out, is_gap_bench_dir, "gap-bench output")
    if args.cases and any(not 1 <= c <= len(SUITE) for c in args.cases):
        raise CimlError(f"--cases: case numbers are 1 to {len(SUITE)}, got {args.cases}")
    doc = gap_bench(args.out, args.cases, cap_jobs(args.jobs), args.scale, cluster=args.cluster)
    print(table(doc["cases"]))
    print(json.dumps(doc["summary"], indent=1))
    print(f"gap-bench: results in {os.path.join(args.out, 'gap_bench.json')} and gap_bench.md")
    return 0
