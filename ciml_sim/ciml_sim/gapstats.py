"""Scores of the randomised gap-bench with their uncertainty (issue 31): rates with binomial 95 %
intervals, the calibration curve, the confusion matrix and the detection limit per effect type.

Pure functions of the scored cases (gaprandom.score_random_case), no simulator: the tests build the
cases by hand. Rates are k of n with a Wilson 95 % interval (scipy's binomtest): the honest width of
"40 of 42". The intervals treat every parameter as an independent trial; the components of one
effect (a payload's CoM x, y, z) are not, so the coverage intervals are somewhat too narrow.
"""
from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
from scipy.stats import binomtest, norm

from .gapbench import SPURIOUS_SHARE, UNEXPLAINED_LARGE

LEVELS = (0.50, 0.68, 0.90, 0.95, 0.99)
"""Nominal levels of the calibration curve."""
DETECTION_RATE = 0.90
"""A size is detected when the effects at least this large are named right this often."""
MIN_DETECTION_DRAWS = 10
"""Draws at or above a size needed before a detection limit is stated."""
NOTHING, UNEXPLAINED, WRONG_PLACE = "nothing", "unexplained", "wrong place"
"""Confusion-matrix columns besides the effect types: no effect named, the gap left unexplained,
the right type named at another joint or link."""
NOMINAL_ROW = "none (nominal)"
CONFIDENT_SHARE = 0.3
"""An out-of-catalogue effect counts as named wrong when a catalogue effect takes this share."""


def rate(k: int, n: int) -> dict:
    """k of n with its Wilson 95 % interval (fraction and interval None for n = 0)."""
    if n == 0:
        return {"k": 0, "n": 0, "fraction": None, "ci95": None}
    ci = binomtest(k, n).proportion_ci(0.95, method="wilson")
    return {"k": int(k), "n": int(n), "fraction": k / n, "ci95": [float(ci.low), float(ci.high)]}


def _z(level: float) -> float:
    return float(norm.ppf(0.5 + level / 2))


def _ratios(rows: Iterable[dict]) -> list[float]:
    """|error| / std of every scored parameter of these effect rows (None: a zero std that missed)."""
    out: list[float] = []
    for r in rows:
        cov = r.get("coverage") or {}
        out += [np.inf if x is None else float(x) for x in cov.get("error_over_std", [])]
    return out


def calibration(rows: Sequence[dict], levels: Sequence[float] = LEVELS) -> dict:
    """Measured coverage of the central intervals at each nominal level: {level: rate}."""
    ratios = np.asarray(_ratios(rows), float)
    return {f"{p:.2f}": rate(int(np.sum(ratios <= _z(p))), ratios.size) for p in levels}


def named_in_catalogue(row: dict, diagnosis_effects: Sequence[dict], spurious: Sequence[dict],
                       unexplained_share: float) -> str:
    """The confusion column of one true in-catalogue effect: its type when named at its place; else
    the type named at its place (largest share); else WRONG_PLACE (its type named elsewhere); else the
    case's largest spurious effect (named where no true effect is: what took the missed effect's
    share); else UNEXPLAINED or NOTHING."""
    if row["type_right"] and row["location_right"]:
        return str(row["type"])
    where = set(row["location"])
    here = [f for f in diagnosis_effects if float(f.get("share", 0.0)) > SPURIOUS_SHARE
            and (where & _places(f) or "all" in where | _places(f))]
    if here:
        return str(max(here, key=lambda f: float(f.get("share", 0.0)))["type"])
    if row["type_right"]:
        return WRONG_PLACE
    if spurious:
        return str(max(spurious, key=lambda f: float(f.get("share") or 0.0))["type"])
    return UNEXPLAINED if unexplained_share >= UNEXPLAINED_LARGE else NOTHING


def _places(effect: dict) -> set[str]:
    for key in ("joint", "joints", "link"):
        if key in effect:
            v = effect[key]
            return {v} if isinstance(v, str) else set(v)
    return {"base"}


def named_without_catalogue(diagnosis_effects: Sequence[dict], unexplained_share: float, at_noise_floor: bool,
                            min_share: float) -> str:
    """The confusion column of a case whose truth the catalogue cannot name (nominal: min_share the
    spurious threshold; out of catalogue: CONFIDENT_SHARE): the largest named effect above min_share,
    else UNEXPLAINED (a large unexplained share above the noise floor) or NOTHING."""
    named = [f for f in diagnosis_effects if float(f.get("share", 0.0)) > min_share]
    if named:
        return str(max(named, key=lambda f: float(f.get("share", 0.0)))["type"])
    return UNEXPLAINED if unexplained_share >= UNEXPLAINED_LARGE and not at_noise_floor else NOTHING


def confusion(cases: Sequence[dict]) -> dict[str, dict[str, int]]:
    """true → named → count over the cases' `confusion` entries ([true, named] pairs)."""
    out: dict[str, dict[str, int]] = {}
    for c in cases:
        for true, named in c.get("confusion", []):
            row = out.setdefault(true, {})
            row[named] = row.get(named, 0) + 1
    return out


def detection_limit(draws: Sequence[tuple[float, bool]], rate_needed: float = DETECTION_RATE,
                    min_draws: int = MIN_DETECTION_DRAWS) -> dict:
    """The smallest drawn size s such that every run of min_draws consecutive draws (by size) from s up
    was named right in ≥ rate_needed of them — local windows, so that many large, easy draws cannot
    hide the misses just above s; else why not ("too few draws" or "not reached")."""
    pts = sorted(draws)
    if len(pts) < min_draws:
        return {"limit": None, "draws": len(pts), "why": f"too few draws ({len(pts)} < {min_draws})"}
    hits = np.array([h for _, h in pts], float)
    window_ok = np.convolve(hits, np.ones(min_draws), "valid") >= rate_needed * min_draws - 1e-9
    # window_ok[i]: draws i … i+min_draws−1; the limit is the first i from which every window is ok
    bad = np.nonzero(~window_ok)[0]
    first = int(bad[-1]) + 1 if bad.size else 0
    if first >= window_ok.size:
        return {"limit": None, "draws": len(pts),
                "why": f"not reached: the {min_draws} largest draws are named right < {rate_needed:.0%}"}
    above = hits[first:]
    return {"limit": float(pts[first][0]), "draws": len(pts), "draws_above": int(above.size),
            "named_right_above": rate(int(above.sum()), int(above.size))}


def _median(xs: Iterable[float | None]) -> float | None:
    v = [float(x) for x in xs if x is not None]
    return float(np.median(v)) if v else None


def summarise_random(cases: Sequence[dict]) -> dict:
    """Every score of issue 31 item 2 over the scored random cases (failed cases are counted, not scored)."""
    ok = [c for c in cases if "error" not in c]
    rows = [r for c in ok for r in c.get("effects", [])]
    types = sorted({r["type"] for r in rows})
    nominal = [c for c in ok if c["kind"] == "nominal"]
    ooc = [c for c in ok if c["kind"] == "out_of_catalogue"]
    cat = [c for c in ok if c["kind"] == "catalogue"]

    def right(r: dict) -> bool:
        return bool(r["type_right"] and r["location_right"])

    per_type = {}
    for t in types:
        tr = [r for r in rows if r["type"] == t]
        per_type[t] = {"named_right": rate(sum(right(r) for r in tr), len(tr)),
                       "calibration": calibration(tr),
                       "detection_limit": detection_limit([(r["size"], right(r)) for r in tr]),
                       "size": tr[0]["size_unit"],
                       "median_param_rel_error": _median(r["param_rel_error"] for r in tr)}
    ooc_ok = sum(1 for c in ooc if (o := c["out_of_catalogue"])["unexplained_large"] and o["localised_right"]
                 and not o["named_wrong_with_confidence"])
    return {
        "cases": len(cases), "failed_cases": len(cases) - len(ok),
        "kinds": {"catalogue": len(cat), "nominal": len(nominal), "out_of_catalogue": len(ooc)},
        "in_catalogue_effects": len(rows),
        "named_right": rate(sum(right(r) for r in rows), len(rows)),
        "false_positive_nominal": rate(sum(1 for c in nominal if c["named"] not in (NOTHING, UNEXPLAINED)),
                                       len(nominal)),
        "unexplained_alarm_nominal": rate(sum(1 for c in nominal if c["named"] == UNEXPLAINED), len(nominal)),
        "cases_with_spurious_effect": rate(sum(1 for c in cat if c.get("spurious")), len(cat)),
        "out_of_catalogue_unexplained_and_localised": rate(ooc_ok, len(ooc)),
        "calibration": calibration(rows),
        "per_type": per_type,
        "confusion": confusion(ok),
        "median_param_rel_error": _median(r["param_rel_error"] for r in rows),
        "median_heldout_shrink": _median(c.get("shrink_ratio") for c in cat),
        "median_heldout_shrink_physical": _median(c.get("shrink_ratio_physical") for c in cat),
        "median_resimulated_shrink": _median(c.get("resim_shrink") for c in cat),
        "median_resimulated_shrink_oracle": _median(c.get("resim_shrink_oracle") for c in cat),
        "median_case_s": _median(c.get("record_s", 0) + c.get("diagnose_s", 0) + c.get("verify_s", 0) for c in ok),
        "targets": {"named_right": ">= 0.95", "false_positive_nominal": "<= 0.05",
                    "calibration 0.95": "within [0.90, 0.98]", "calibration 0.68": "within [0.60, 0.76]",
                    "out_of_catalogue_unexplained_and_localised": ">= 0.80"},
    }
