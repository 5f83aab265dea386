"""The sim-to-real gap diagnosis end to end (docs/ARCHITECTURE.md §6): bags in, diagnosis.json and report.html out.

The diagnosis reads bags only through ciml_learning.logs.pipeline.load_dataset, i.e. only the four
sensor topics (/joint_states, /base_state, /contact_state, /torque_command): nothing under
/sim/, no scenario name or effect list can reach it.

Held-out data: the --heldout bags; without them, whole bags are held out (the last ~30 %,
at least one) or, with a single bag, its last ~30 % of time (the filter's half window on
either side of the cut is left out of both parts).

Steps: regression rows of every observed Φ̃' entry and Γ (features.py) → noise levels, greedy
selection on held-out data with the command-update sampling baseline in every model, physical
bounds, relevance and consistency checks (identification.py) → block-bootstrap uncertainty →
localisation of the error left after the baseline (localization.py) → held-out shrink, with
the per-sample stiction estimate of identified Coulomb frictions (shrink.py) → diagnosis.json
(docs/ARCHITECTURE.md §6 keys plus `baseline`, `selection`, `model`) and report.html (report.py).
"""
from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence

import numpy as np

from ciml_learning.core.fileio import check_out_dir
from ciml_learning.core.robot import RobotDescription
from ciml_learning.diagnosis.bounds import physical_ranges
from ciml_learning.diagnosis.candidates import COULOMB_SMOOTHING, UNMODELLED_SENSOR_TYPE, FeatureLayout, link_inertias
from ciml_learning.diagnosis.effects import DiagnosisError
from ciml_learning.diagnosis.features import build_rows, grams, predict
from ciml_learning.diagnosis.files import IDENTIFIED_SCENARIO, is_diagnosis_dir, write_diagnosis_dir
from ciml_learning.diagnosis.identification import (
    parameter_uncertainty,
    physical_parameters,
    pooled_command_sampling,
    relevance_function,
    select,
)
from ciml_learning.diagnosis.identified import identified_scenario_yaml
from ciml_learning.diagnosis.localization import dimension_names, leg_summary, localize
from ciml_learning.diagnosis.report import render_report
from ciml_learning.diagnosis.shrink import project_stuck, residual_series, residuals, shrink, stuck_ss
from ciml_learning.diagnosis.uncertainty import Z68, Z95
from ciml_learning.effects import EFFECTS
from ciml_learning.learning.cluster import bag_mapper
from ciml_learning.logs.pipeline import load_dataset

FORMAT_VERSION = 1
HELDOUT_FRACTION = 0.3
MIN_SAMPLES = 250
"""Fewest valid samples (1 s at 250 Hz) in each of the identification and held-out parts."""


def _say(progress: bool, msg: str) -> None:
    if progress:
        print(f"[diagnose] {msg}", file=sys.stderr, flush=True)


def split_heldout(dataset, fraction: float = HELDOUT_FRACTION) -> tuple[np.ndarray, np.ndarray, str]:
    """(identification samples, held-out samples, description) of one dataset without --heldout."""
    from ciml_learning.core.filters import delay_for_rate

    n_bags = len(dataset.bags)
    idx = np.arange(len(dataset.targets.t))
    if n_bags >= 2:
        k = max(1, int(round(fraction * n_bags)))
        held = set(range(n_bags - k, n_bags))
        mask = np.isin(dataset.bag_index, list(held))
        names = [dataset.bags[i] for i in sorted(held)]
        return idx[~mask], idx[mask], f"whole bags held out: {', '.join(names)}"
    t = dataset.targets.t
    cut = int(np.searchsorted(t, t[0] + (1 - fraction) * (t[-1] - t[0])))
    guard = delay_for_rate(dataset.rate_hz)  # the filter's half window at the log's rate
    return (idx[: max(0, cut - guard)], idx[cut + guard:],
            f"last {fraction:.0%} of time held out of {dataset.bags[0]} (t ≥ {t[cut] - t[0]:.2f} s from its start)")


MIN_SUBSET_SAMPLES = 250


def corrected_rows(rows, model):
    """Rows whose measured errors have a (baseline) model's prediction removed."""
    import dataclasses

    from ciml_learning.diagnosis.features import predict

    pr, pa = predict(rows, model.feature_theta())
    return dataclasses.replace(rows, y_rbd=rows.y_rbd - pr, y_act=rows.y_act - pa)


def consistency_subsets(robot: RobotDescription, dataset, rows) -> list:
    """Grams of parts of the identification data: each contact configuration and each bag with
    at least MIN_SUBSET_SAMPLES samples (identification.consistency)."""
    contacts = dataset.log.contacts[rows.samples]
    keys = {"contacts": contacts @ (1 << np.arange(robot.n_feet)), "bag": dataset.bag_index[rows.samples]}
    out = []
    for arr in keys.values():
        values = np.unique(arr)
        if len(values) < 2:
            continue
        for v in values:
            keep = arr == v
            if keep.sum() >= MIN_SUBSET_SAMPLES:
                out.append(grams(rows.subset(keep)))
    return out


def friction_speed_subsets(robot: RobotDescription, dataset, rows):
    """candidate → Grams of its joint's sliding samples (|q̇_j| ≥ V_STICK) in three speed bins, for
    joint friction candidates (identification.consistency); cached per joint."""
    from ciml_learning.diagnosis.shrink import V_STICK

    cache: dict[str, list] = {}
    speed = np.abs(dataset.log.v[rows.samples, 6:])

    def subsets(cand) -> list:
        kind = EFFECTS.get(cand.type)  # None for the baseline and the probes
        if kind is None or not kind.speed_bins or cand.joint is None:
            return []
        if cand.joint not in cache:
            v = speed[:, robot.joint_names.index(cand.joint)]
            sliding = v >= V_STICK
            out = []
            if sliding.sum() >= 3 * MIN_SUBSET_SAMPLES:
                edges = np.quantile(v[sliding], [1 / 3, 2 / 3])
                for lo, hi in ((V_STICK, edges[0]), (edges[0], edges[1]), (edges[1], np.inf)):
                    out.append(grams(rows.subset((v >= lo) & (v < hi))))
            cache[cand.joint] = out
        return cache[cand.joint]

    return subsets




def effect_shares(sel, rows_ho, res, v_ho: np.ndarray, stick: list[int]) -> list[float]:
    """Each selected term's share of the held-out gap above the noise floor (identification.Selection.
    unexplained_share). The selection saw the stuck joints' torques projected out (identify): a term's
    share is its drop-one cost there, plus, in the directions projected out (shrink.stuck_ss), what its
    stiction estimate removes and its part of what the terms' laws explain there, in proportion to its
    own drop-one cost there (no refit). The gap counts those directions' nominal error in full (their
    noise is not taken off). Without stuck joints: the selection's shares."""
    if sel.gap_at_noise_floor:
        return [0.0] * len(sel.shares)
    gains = [res.stiction_gain.get(c.label, 0.0) for c in sel.effects]
    if not stick:
        shares = [sh + g / sel.gap_ss for sh, g in zip(sel.shares, gains)]
    else:
        own = [predict(rows_ho, sel.model.part([c]).feature_theta())[0] for c in sel.effects]
        base = rows_ho.y_rbd - sum(own, np.zeros(len(rows_ho.y_rbd)))  # every term, no stiction estimate
        ss = stuck_ss(rows_ho, np.column_stack([rows_ho.y_rbd, res.rbd, base] + [base + o for o in own]), v_ho,
                      stick, sel.sigma)
        nominal, final, without = ss[0], ss[1], ss[2]
        laws = nominal - final - sum(gains)  # what the terms' own laws explain in the stuck directions
        cost = np.maximum(ss[3:] - without, 0.0)
        gap = sel.gap_ss + nominal
        shares = [(sh * sel.gap_ss + g + (laws * c / cost.sum() if cost.sum() > 0 else 0.0)) / gap
                  for sh, g, c in zip(sel.shares, gains, cost)]
    if sum(shares) > 1.0:  # the residual ended below the estimated noise floor: all of the gap is explained
        shares = [sh / sum(shares) for sh in shares]
    return [max(sh, 0.0) for sh in shares]


MAX_STICK_PASSES = 3


def identify(robot: RobotDescription, layout: FeatureLayout, ds_id, rows_id, rows_ho, v_id: np.ndarray,
             v_ho: np.ndarray):
    """The selection (identification.select), repeated with the torque of each stuck joint whose
    identified friction sticks projected out of its samples (shrink.project_stuck, whitened by the first
    selection's noise levels; each selection fits with its own data's noise levels and reports its gap
    and shares in the first one's, so that they stay in the same units), starting from the previous
    selection's effects (a greedy selection from scratch can stop in a worse set on the new rows),
    until no new such joint is found (at most MAX_STICK_PASSES selections).
    → (selection, identification rows it used, their held-out Grams, those joints)."""
    stick: list[int] = []
    fit_id, fit_ho = rows_id, rows_ho
    start: list | None = None
    sigma = None
    for n_pass in range(MAX_STICK_PASSES):
        g_id, g_ho = grams(fit_id), grams(fit_ho)
        sel = select(layout, g_id, g_ho, subsets=consistency_subsets(robot, ds_id, fit_id),
                     relevance=relevance_function(fit_id, g_id),
                     candidate_subsets=friction_speed_subsets(robot, ds_id, fit_id),
                     start=start, report_sigma=sigma)
        found = {robot.joint_names.index(c.joint) for c, p in zip(sel.model.candidates, physical_parameters(sel.model))
                 if c.type in EFFECTS and (EFFECTS[c.type].stiction(p) or 0.0) > 0.0}
        if found <= set(stick) or n_pass == MAX_STICK_PASSES - 1:
            break
        stick = sorted(set(stick) | found)
        start, sigma = sel.effects, sel.sigma  # the first selection's: kept for the report
        fit_id = project_stuck(rows_id, v_id, stick, sel.sigma)
        fit_ho = project_stuck(rows_ho, v_ho, stick, sel.sigma)
    return sel, fit_id, g_ho, stick


def _interval(params: dict, std: dict, z: float) -> dict:
    out: dict[str, list] = {}
    for k, v in params.items():
        s = std[k]
        if isinstance(v, list):
            out[k] = [[float(a - z * b), float(a + z * b)] for a, b in zip(v, s)]
        else:
            out[k] = [float(v - z * s), float(v + z * s)]
    return out


def _confidence(cand, params: dict, std: dict, spread: float) -> str:
    """high / medium / low: consistent across data subsets (spread) and clear of zero (the main
    parameter's deviation from "no effect" is at least 4 / 2 standard deviations)."""
    key = next(iter(params))
    v, s = params[key], std.get(key)
    if isinstance(v, list):
        return "medium" if spread <= 0.3 else "low"
    null = EFFECTS[cand.type].null.get(key, 0.0)
    z = abs(v - null) / max(float(s), 1e-300) if isinstance(s, float) else np.inf
    if spread <= 0.1 and z >= 4:
        return "high"
    if spread <= 0.3 and z >= 2:
        return "medium"
    return "low"


def _effect_entry(cand, params: dict, std: dict, share: float, spread: float, std_components: dict) -> dict:
    e = {"type": cand.type}
    e.update(cand.location())
    e.update({"params": params, "std": std, "std_components": std_components,
              "interval_95": _interval(params, std, Z95),
              "interval_68": _interval(params, std, Z68), "share": float(share),
              "consistency_spread": float(spread), "status": "identified",
              "confidence": _confidence(cand, params, std, spread)})
    return e


def _unmodelled_entry(layout: FeatureLayout, dataset, samples: np.ndarray, cand, coefficients: np.ndarray,
                      share: float) -> dict:
    """A joint torque outside the catalogue (identification.py): where, its share of the gap (part of
    unexplained_share), the torque it exerts on the joint at the joint's mean position q̄
    (`position_center`), its stiffness there (k: the exerted torque falls by k per rad, a spring's
    k; the model error e is minus the exerted torque) and the RMS of its position-dependent part
    over the identification samples."""
    from ciml_learning.diagnosis.candidates import generic_joint_basis

    j = layout.robot.joint_names.index(cand.joint)
    assert layout.q_center is not None and layout.q_scale is not None  # FeatureLayout sets both
    basis = generic_joint_basis(dataset.log.q[samples, 7:], layout, None)[:, j]
    varying = basis[:, 1:] @ coefficients[1:]
    return {"joint": cand.joint, "share": float(share),
            "position_center": float(layout.q_center[j]),
            "torque_at_center": float(-coefficients[0]),
            "stiffness": float(coefficients[1] / layout.q_scale[j]),
            "torque_position_dependent_rms": float(np.std(varying)),
            "level": "sensor" if cand.type == UNMODELLED_SENSOR_TYPE else "joint",
            "description": ("a position-dependent error of this joint's torque reading (in both Φ̃ and Γ, e.g. a "
                            "sensor ripple) that no catalogue effect explains" if cand.type == UNMODELLED_SENSOR_TYPE
                            else "a position-dependent joint torque at this joint that no catalogue effect explains "
                                 "(e.g. a spring, a cable)") + "; in unexplained_share, not an effect"}


def diagnose(robot: RobotDescription, bags: Sequence[str], heldout: Sequence[str] | None = None,
             out_dir: str | None = None, progress: bool = True, report: bool = True, profile=None,
             reference: Sequence[str] | None = None, jobs: int = 1, cluster: str | None = None) -> dict:
    """Run the diagnosis; write DIR/diagnosis.json (atomically) and DIR/report.html if out_dir.

    profile: the robot profile the bags are read through (None: CIML's own topics).
    reference: bags of the same robot to compare with (e.g. the simulator's logs of the same motions):
    they are diagnosed too, and what distinguishes the bags from them is added (reference.py).
    jobs, cluster: where the bags are read and filtered (cluster.bag_mapper: `jobs` local processes, or a
    Dask cluster; the results are the same)."""
    t_start = time.perf_counter()
    bags = [str(b) for b in bags]
    if not bags:
        raise DiagnosisError("no bag given")
    if out_dir is not None:  # refused before minutes of work, not after
        check_out_dir(out_dir, is_diagnosis_dir, "diagnosis")
    for b in list(bags) + [str(h) for h in heldout or []] + [str(r) for r in reference or []]:
        if not os.path.exists(b):
            raise DiagnosisError(f"bag not found: {b}")
    _say(progress, f"reading {len(bags)} bag(s)")
    map_bags = bag_mapper(jobs, cluster)
    ds_id = load_dataset(robot, bags, progress=progress, profile=profile, map_bags=map_bags)
    if heldout:
        _say(progress, f"reading {len(heldout)} held-out bag(s)")
        ds_ho = load_dataset(robot, [str(b) for b in heldout], progress=progress, profile=profile, map_bags=map_bags)
        id_idx = np.arange(len(ds_id.targets.t))
        ho_idx = np.arange(len(ds_ho.targets.t))
        how = "held-out bags given with --heldout"
    else:
        ds_ho = ds_id
        id_idx, ho_idx, how = split_heldout(ds_id)
    q_id = ds_id.log.q[id_idx, 7:]  # the probe's position scale: the identification data's own range
    layout = FeatureLayout(robot, link_inertias(robot), q_center=q_id.mean(axis=0), q_scale=q_id.std(axis=0))
    _say(progress, f"regressors of {len(layout.candidates)} candidate effects")
    rows_id = build_rows(robot, layout, ds_id, id_idx, progress=progress, desc="regressors (identification)")
    rows_ho = build_rows(robot, layout, ds_ho, ho_idx, progress=progress, desc="regressors (held-out)")
    for name, rows in (("identification", rows_id), ("held-out", rows_ho)):
        if len(rows.samples) < MIN_SAMPLES:
            raise DiagnosisError(f"only {len(rows.samples)} valid {name} samples (need ≥ {MIN_SAMPLES}, "
                                 f"{MIN_SAMPLES / ds_id.rate_hz:.1f} s at the log's {ds_id.rate_hz:.0f} Hz); "
                                 "give longer or more bags")
    _say(progress, "selecting effects on held-out data")
    v_id, v_ho = ds_id.log.v[rows_id.samples, 6:], ds_ho.log.v[rows_ho.samples, 6:]
    sel, fit_id, g_ho, stick = identify(robot, layout, ds_id, rows_id, rows_ho, v_id, v_ho)
    noise_floor = sel.noise_floor
    assert noise_floor is not None  # select() measures it
    _say(progress, "parameter uncertainty (block bootstrap)")
    # what the lag's coefficient reads in these logs (lag_time_constant): their command sampling
    sel.model.sampling = pooled_command_sampling([i["stamp_report"].get("command_sampling") for i in ds_id.inputs],
                                                 1.0 / ds_id.rate_hz)
    std_all, uncertainty = parameter_uncertainty(sel, fit_id, g_ho, fs=ds_id.rate_hz)
    parts_all = uncertainty.pop("components", [])
    params_all = physical_parameters(sel.model)
    nb = sel.n_baseline
    baseline = sel.model.part(sel.model.candidates[:nb])
    effects_model = sel.model.part([c for c in sel.effects if c.in_catalogue])
    _say(progress, "localisation and shrink")
    # the gap is what remains after the baseline (command-update sampling): correct the rows by it
    corr_id, corr_ho = corrected_rows(rows_id, baseline), corrected_rows(rows_ho, baseline)
    loc = localize(robot, [(ds_id, corr_id), (ds_ho, corr_ho)], sel.sigma)
    raw_loc = {x["dimension"]: x["rms_error"] for x in localize(robot, [(ds_id, rows_id), (ds_ho, rows_ho)], sel.sigma)}
    for x in loc:
        x["rms_error_before_baseline"] = raw_loc[x["dimension"]]
    res = residuals(corr_ho, effects_model, sel.weights, v_ho)
    shr = shrink(robot, corr_ho, res, sel.sigma, noise_floor)
    raw = shrink(robot, rows_ho, residuals(rows_ho, baseline, sel.weights, v_ho), sel.sigma)
    shr["baseline"] = {"heldout_rms_before_baseline": raw["heldout_rms_nominal"],
                       "heldout_rms_after_baseline": raw["heldout_rms_with_effects"]}
    shares = effect_shares(sel, corr_ho, res, v_ho, stick)
    found = list(zip(sel.effects, params_all[nb:], std_all[nb:], parts_all[nb:], shares, sel.spread))
    effects = [_effect_entry(c, p, s, sh, sp, parts) for c, p, s, parts, sh, sp in found if c.in_catalogue]
    effects.sort(key=lambda e: -e["share"])
    # what the out-of-catalogue probe explains stays unexplained, localised at its joint
    unexplained = 0.0 if sel.gap_at_noise_floor else 1.0 - sum(e["share"] for e in effects)
    outside = [_unmodelled_entry(layout, ds_id, id_idx, c, sel.model.params_of(c), sh)
               for c, _, _, _, sh, _ in found if not c.in_catalogue]
    names = dimension_names(robot)
    result = {
        "format_version": FORMAT_VERSION,
        "localization": loc,
        "localization_by_leg": leg_summary(robot, loc),
        "effects": effects,
        "baseline": {
            "type": "command_update_sampling",
            "params": params_all[0], "std": std_all[0],
            "at_bound": [n for n, v, lo, hi in zip(sel.model.candidates[0].param_names, sel.model.theta[:3],
                                                   sel.model.candidates[0].lower, sel.model.candidates[0].upper)
                         if np.isclose(v, lo) or np.isclose(v, hi)],
            "description": "not an effect of the robot: the log samples the joint loop's torque just before "
                           "each new command acts; e_j = qd*q'_j + qdd*q''_j + udot*u'_j on every joint "
                           "(expected qd = -Kp*dt/2, qdd = -Kd*dt/2, udot = -dt/2, dt the tick). Fitted with "
                           "every model; the gap is what remains after it.",
        },
        "unexplained_share": float(max(0.0, unexplained)),
        "unexplained_share_with_noise": sel.unexplained_share_with_noise,
        "gap_at_noise_floor": bool(sel.gap_at_noise_floor),
        "noise_floor": {
            "description": "held-out error no model can remove (per dimension, N or Nm): an in-sample fit of "
                           "every catalogue term on the held-out data, capped at its pool's median; "
                           "unexplained_share and the effects' shares count only the gap above it",
            "share_of_nominal": float(sel.floor_ss / sel.nominal_ss) if sel.nominal_ss > 0 else 0.0,
            "per_dimension": {n: float(f) for n, f in zip(dimension_names(robot), noise_floor)},
        },
        "not_identified": sel.not_identified,
        "bounds": physical_ranges(robot),
        "uncertainty": uncertainty,
        "unexplained_localised": outside,
        "shrink": shr,
        "data": {
            "bags": bags,
            "heldout_bags": [str(b) for b in heldout] if heldout else [],
            "heldout": how,
            "samples": int(len(rows_id.samples)),
            "stuck_joints_projected_out": [robot.joint_names[j] for j in stick],
            "heldout_samples": int(len(rows_ho.samples)),
            "rejected": {k: int(v) for k, v in ds_id.rejected.items()},
            "rate_hz": ds_id.rate_hz,
            "actuation_observed": bool(ds_id.u_observed and ds_ho.u_observed),
            "warnings": ds_id.warnings + [w for w in ds_ho.warnings if w not in ds_id.warnings],
            "inputs": [{k: i[k] for k in ("bag", "rate_hz", "u_observed", "sources")}
                       | {"stamp_problems": i["stamp_report"].get("problems", [])}
                       for i in ds_id.inputs + (ds_ho.inputs if heldout else [])],
        },
        "selection": {
            "steps": [{"accepted": s.accepted, "gain_share": s.gain_share, "runner_up": s.runner_up,
                       "runner_up_share": s.runner_up_share} for s in sel.steps],
            "candidates": len(layout.candidates),
            "noise_level": {n: float(s) for n, s in zip(names, sel.sigma)},
            "rejected_as_inconsistent": [{"candidate": lab, "spread": sp} for lab, sp in sel.rejected],
            "nominal_heldout_ss": sel.nominal_ss,
            "final_heldout_ss": sel.final_ss,
        },
        "model": {
            "format_version": 1,
            "description": "nominal model + these effects; Phi~ = e(q, qd, qdd), Gamma = tau - u "
                           "(ciml_learning.diagnosis.effects.EffectModel)",
            "joint_names": list(robot.joint_names),
            "foot_frames": list(robot.foot_frames),
            "coulomb_smoothing": COULOMB_SMOOTHING,
            "effects": [{k: v for k, v in e.items() if k in ("type", "joint", "joints", "link", "params")}
                        for e in effects],
        },
        "time_s": round(time.perf_counter() - t_start, 2),
    }
    if reference:
        from ciml_learning.diagnosis.reference import compare, reference_summary

        _say(progress, f"diagnosing {len(reference)} reference bag(s) against the nominal model")
        ref = diagnose(robot, [str(r) for r in reference], None, None, progress=progress, report=False, profile=profile,
                       jobs=jobs, cluster=cluster)
        result["reference"] = reference_summary(ref, [str(r) for r in reference])
        result["reference_comparison"] = compare(result, ref)
    _check_finite(result)
    if out_dir is not None:
        html = None
        if report:
            _say(progress, "report")
            series = residual_series(corr_ho, res, sel.sigma, ds_ho.targets.t)
            html = render_report(robot, result, series, rows_ho, sel)
        write_diagnosis_dir(out_dir, result, html, files={IDENTIFIED_SCENARIO: identified_scenario_yaml(result)})
        result["time_s"] = round(time.perf_counter() - t_start, 2)
    return result


def _check_finite(obj, path: str = "") -> None:
    """NaN never reaches an output: fail loudly instead (a bug, not bad input)."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            _check_finite(v, f"{path}.{k}")
    elif isinstance(obj, (list, tuple)):
        for i, v in enumerate(obj):
            _check_finite(v, f"{path}[{i}]")
    elif isinstance(obj, float) and not np.isfinite(obj):
        raise DiagnosisError(f"non-finite value at {path or 'result'}; the data may be degenerate")
