#!/usr/bin/env python3
"""Last step of the demo: print where the report is and its three answers in a few lines."""
from __future__ import annotations

import json
import os
import sys


def _load(path: str) -> dict:
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def _metrics(doc: dict) -> dict:
    return doc.get("metrics", doc)


def main(out: str) -> int:
    diag = _load(os.path.join(out, "diagnosis", "diagnosis.json"))
    where = ", ".join(f"{d['dimension']} ({100 * d['share']:.0f} %)" for d in diag["localization"][:4])
    def where_of(e: dict) -> str:
        joints = e.get("joints", [])
        return e.get("joint") or e.get("link") or (joints if isinstance(joints, str) else ", ".join(joints)) or "base"

    which = "; ".join(
        f"{e['type']} at {where_of(e)} "
        + ", ".join(f"{k}={v:.3g}±{e.get('std', {}).get(k, float('nan')):.2g}" for k, v in e["params"].items()
                    if isinstance(v, (int, float)))
        + "".join(f", {k}=[{', '.join(f'{x:.3g}' for x in v)}]" for k, v in e["params"].items() if isinstance(v, list))
        + f" ({100 * e['share']:.0f} % of the gap)"
        for e in diag["effects"][:6]) or "no catalogue effect explains the gap"
    s = diag["shrink"]
    print()
    print(f"Report: {os.path.abspath(os.path.join(out, 'diagnosis', 'report.html'))}")
    print(f"  Where:  {where}")
    print(f"  Which:  {which}; unexplained {100 * diag['unexplained_share']:.0f} %")
    print(f"  Shrink: held-out RMS {s['heldout_rms_nominal']:.3g} -> {s['heldout_rms_with_effects']:.3g} "
          f"({100 * s['ratio']:.0f} % of the gap removed)")
    rows = []
    for name, label in (("nominal", "nominal"), ("model_sgpr", "learned (SGPR)"), ("diagnosis", "identified effects")):
        path = os.path.join(out, f"closed_loop_{name}.json")
        if os.path.exists(path):
            m = _metrics(_load(path))
            fallbacks = f"   ({m['qp_failures']} QP fallbacks)" if m.get("qp_failures") else ""
            rows.append(f"    {label:<20} feedback {m['rms_feedback_effort_nm']:6.1f} Nm   joint error "
                        f"{m['rms_joint_error_deg']:5.2f} deg   base {m['rms_base_position_error_mm']:5.1f} mm"
                        f"{'   FELL' if m.get('fell') else ''}{fallbacks}")
    if rows:
        print("  Closed loop, trot 35 cm (new execution):")
        print("\n".join(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "out/demo"))
