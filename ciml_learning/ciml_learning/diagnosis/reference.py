"""Sim-to-real against a reference: what distinguishes the real logs from the reference logs of
the same robot (`ciml diagnose --bag REAL... --reference SIM...`, docs/DIAGNOSIS.md).

Both sets of logs are diagnosed against the nominal model with the same method (run.diagnose);
their identified effects are then compared effect by effect (same type at the same place):

- present in the real logs only (or only in the reference): a difference, with its parameters
  and uncertainty as identified;
- present in both: the difference of each parameter, real − reference, with the standard
  deviation √(σ_real² + σ_ref²); it is a difference when the main parameter's difference
  exceeds SIGNIFICANCE standard deviations, otherwise the effect is shared (an error of both
  logs, e.g. of their command reconstruction, or of the URDF: not a sim-to-real gap).

Estimates "at bound — not identified" in either diagnosis are listed, never compared.
"""
from __future__ import annotations

from typing import Any

import numpy as np

SIGNIFICANCE = 1.959964
"""A shared effect's main parameter differs when |real − reference| > this many standard deviations (95 %)."""


def effect_key(e: dict) -> tuple[str, str]:
    """(type, place) of an identified effect: its joint, link, 'all' joints or the base."""
    where = e.get("joint") or e.get("link") or ("all" if e.get("joints") == "all" else "base")
    return e["type"], where


def _difference(real: dict, ref: dict) -> tuple[dict, dict]:
    diff, std = {}, {}
    for k, v in real["params"].items():
        if k not in ref["params"]:
            continue
        a, b = np.atleast_1d(np.asarray(v, float)), np.atleast_1d(np.asarray(ref["params"][k], float))
        sa = np.atleast_1d(np.asarray(real.get("std", {}).get(k, np.zeros_like(a)), float))
        sb = np.atleast_1d(np.asarray(ref.get("std", {}).get(k, np.zeros_like(b)), float))
        d, s = a - b, np.sqrt(sa ** 2 + sb ** 2)
        diff[k] = d.tolist() if isinstance(v, list) else float(d[0])
        std[k] = s.tolist() if isinstance(v, list) else float(s[0])
    return diff, std


def compare(real: dict, reference: dict) -> dict:
    """The `reference_comparison` object of diagnosis.json from two diagnoses (module docstring)."""
    ref_by_key = {effect_key(e): e for e in reference.get("effects", [])}
    real_by_key = {effect_key(e): e for e in real.get("effects", [])}
    rows: list[dict[str, Any]] = []
    for key, e in real_by_key.items():
        base = {"type": key[0], "where": key[1]}
        if key not in ref_by_key:
            rows.append(base | {"status": "real only", "params": e["params"], "std": e["std"],
                                "interval_95": e.get("interval_95"), "share_real": e["share"]})
            continue
        r = ref_by_key[key]
        diff, std = _difference(e, r)
        main = next(iter(diff), None)
        z = (np.max(np.abs(np.atleast_1d(diff[main])) / np.maximum(np.atleast_1d(std[main]), 1e-300))
             if main is not None else 0.0)
        rows.append(base | {"status": "differs" if z > SIGNIFICANCE else "shared",
                            "params_real": e["params"], "params_reference": r["params"],
                            "difference": diff, "difference_std": std, "difference_z": float(z),
                            "share_real": e["share"], "share_reference": r["share"]})
    for key, r in ref_by_key.items():
        if key not in real_by_key:
            rows.append({"type": key[0], "where": key[1], "status": "reference only", "params": r["params"],
                         "std": r["std"], "interval_95": r.get("interval_95"), "share_reference": r["share"]})
    order = {"real only": 0, "differs": 1, "reference only": 2, "shared": 3}
    rows.sort(key=lambda x: (order[x["status"]], -x.get("share_real", x.get("share_reference", 0.0))))
    return {
        "description": "effects identified in the real logs and in the reference logs (each against the nominal "
                       "model), compared effect by effect: 'real only' and 'differs' distinguish the real "
                       "logs from the reference; 'shared' effects are errors of both (not a sim-to-real gap)",
        "significance_z": SIGNIFICANCE,
        "effects": rows,
        "differences": [x for x in rows if x["status"] in ("real only", "differs", "reference only")],
        "not_identified_real": real.get("not_identified", []),
        "not_identified_reference": reference.get("not_identified", []),
    }


def reference_summary(reference: dict, bags: list[str]) -> dict:
    """The reference logs' own diagnosis against the nominal model (the keys a reader compares)."""
    keys = ("effects", "unexplained_share", "unexplained_localised", "not_identified", "baseline", "gap_at_noise_floor")
    out = {k: reference[k] for k in keys if k in reference}
    out["bags"] = list(bags)
    s = reference.get("shrink", {})
    out["shrink"] = {k: s[k] for k in ("ratio", "ratio_physical", "heldout_rms_nominal", "heldout_rms_with_effects",
                                       "worsened_dimensions") if k in s}
    out["localization"] = reference.get("localization", [])[:6]
    return out
