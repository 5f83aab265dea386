"""A random bench scored again as if the misspecification bound counted as 1/SCALE standard deviations
(uncertainty.MISSPECIFICATION_SCALE): only what a parameter's std decides changes — its std, its
68 % and 95 % intervals and its effect's confidence (which the out-of-catalogue score reads); the
estimates, the named effects and the shares are the run's own.

    python results/gap_random_200/rescale.py OUT_DIR SCALE [SCALE ...]

Each case's diagnosis.json (a bench run whose effects keep `std_components`) is rewritten into a copy
of OUT_DIR's scoring files (draws.json, gap_bench.json, case_NN/diagnosis/diagnosis.json and
verify/verify.json) in a temporary folder, which gaprandom.rescore scores as the bench does. Prints
per scale the summary's named-right, false-positive, out-of-catalogue and coverage rows (overall and
per type with ≥ 20 parameters); the JSON of each scale goes to OUT_DIR/rescaled_SCALE.json.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
import tempfile
from types import SimpleNamespace

import numpy as np

from ciml_learning.diagnosis import run
from ciml_learning.diagnosis.uncertainty import MISSPECIFICATION_SCALE, Z68, Z95, combine
from ciml_sim import gaprandom


def rescaled(effect: dict, scale: float) -> dict:
    """The effect as the diagnosis would report it with the misspecification bound at `scale`."""
    comps = effect.get("std_components")
    if not comps:
        return effect
    factor = {name: (scale / MISSPECIFICATION_SCALE if name == "misspecification" else 1.0) for name in comps}
    std = {}
    for key, value in effect["params"].items():
        parts = [np.asarray(comps[name][key], float) * factor[name] for name in comps]
        s = combine(*parts)
        std[key] = s.tolist() if isinstance(value, list) else float(s)
    out = dict(effect, std=std)
    out["interval_95"] = run._interval(effect["params"], std, Z95)
    out["interval_68"] = run._interval(effect["params"], std, Z68)
    if effect.get("confidence") is not None:  # an effect at a physical bound has none, at any scale
        out["confidence"] = run._confidence(SimpleNamespace(type=effect["type"]), effect["params"], std,
                                            effect["consistency_spread"])
    return out


def copy_rescaled(src: str, dst: str, scale: float) -> None:
    for name in ("draws.json", "gap_bench.json"):  # gap_bench.json: the run's timings (none while it runs)
        if os.path.isfile(os.path.join(src, name)):
            shutil.copy(os.path.join(src, name), dst)
    for case in sorted(d for d in os.listdir(src) if d.startswith("case_")):
        diag = os.path.join(src, case, "diagnosis", "diagnosis.json")
        if not os.path.isfile(diag):
            continue
        os.makedirs(os.path.join(dst, case, "diagnosis"))
        with open(diag, encoding="utf-8") as f:
            d = json.load(f)
        d["effects"] = [rescaled(e, scale) for e in d.get("effects") or []]
        with open(os.path.join(dst, case, "diagnosis", "diagnosis.json"), "w", encoding="utf-8") as f:
            json.dump(d, f)
        verify = os.path.join(src, case, "verify", "verify.json")
        if os.path.isfile(verify):
            os.makedirs(os.path.join(dst, case, "verify"))
            shutil.copy(verify, os.path.join(dst, case, "verify"))


def main() -> None:
    src, scales = sys.argv[1], [float(x) for x in sys.argv[2:]]
    for scale in scales:
        with tempfile.TemporaryDirectory() as tmp:
            copy_rescaled(src, tmp, scale)
            summary = gaprandom.rescore(tmp)
        with open(os.path.join(src, f"rescaled_{scale:g}.json"), "w", encoding="utf-8") as f:
            json.dump(summary, f, indent=1)
        print(f"scale {scale:g}: " + "; ".join(f"{k} {_rate(summary['summary'][k])}" for k in ROWS)
              + "; " + "; ".join(f"in {level} {_rate(summary['summary']['calibration'][level])}" for level in LEVELS))
        for t, per in sorted(summary["summary"]["per_type"].items()):
            cal = per.get("calibration", {})
            if cal.get("0.68", {}).get("n", 0) >= 20:
                print(f"    {t}: " + "; ".join(f"in {level} {_rate(cal[level])}" for level in LEVELS))


ROWS = ("named_right", "false_positive_nominal", "out_of_catalogue_unexplained_and_localised")
LEVELS = ("0.68", "0.95")


def _rate(r: dict) -> str:
    if not r.get("n"):
        return "—"
    return f"{r['k']}/{r['n']} = {100 * r['fraction']:.1f} % [{100 * r['ci95'][0]:.1f}, {100 * r['ci95'][1]:.1f}]"

if __name__ == "__main__":
    main()
