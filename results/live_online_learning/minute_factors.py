"""What goes with a slow go1 run: per run and minute, the cut in feedback effort against the mean of
the runs without learning, beside the learner's samples, the snapshots it served and the share of
the controller's steps whose ε entry the trust law gated; then the correlation of each with the cut
over minutes 2–6 of every run.

    python results/live_online_learning/minute_factors.py A.json B.json ...
"""
from __future__ import annotations

import sys

import numpy as np
from tally import runs


def per_minute(periods: list[dict], key: str, i: int) -> float:
    """The counter's increase in minute i (0-based; counters are cumulative)."""
    now = float(periods[i].get(key) or 0.0)
    return now - (float(periods[i - 1].get(key) or 0.0) if i > 0 else 0.0)


def main(paths: list[str]) -> None:
    all_runs = runs(paths)
    base = np.mean([[p["effort_rms_nm"] for p in r["periods"][:10]] for r in all_runs if not r["online"]], axis=0)
    print("without learning, per minute [Nm]: " + ", ".join(f"{b:.2f}" for b in base))
    print("\n| seed | cut in minutes 1–6 [%] | samples learned per minute, 1–4 | ε gated, minutes 1–4 [%] |\n"
          "|---|---|---|---|")
    rows = []
    for r in (r for r in all_runs if r["online"]):
        p = r["periods"]
        cut = [100 * (1 - p[i]["effort_rms_nm"] / base[i]) for i in range(min(10, len(p)))]
        learned = [per_minute(p, "online_learner.samples_learned", i) for i in range(len(p))]
        gated = [100 * per_minute(p, "id_controller.epsilon_gated", i)
                 / max(1.0, per_minute(p, "id_controller.commands", i)) for i in range(len(p))]
        print(f"| {r['seed']} | {' '.join(f'{c:.1f}' for c in cut[:6])} | "
              f"{' '.join(f'{x:.0f}' for x in learned[:4])} | {' '.join(f'{g:.0f}' for g in gated[:4])} |")
        rows += [(cut[i], gated[i], learned[i], per_minute(p, "state_filter.states_valid", i)) for i in range(1, 6)]
    a = np.array(rows)
    print(f"\ncorrelation with the cut over minutes 2–6 ({len(a)} run-minutes): "
          + ", ".join(f"{name} {np.corrcoef(a[:, k], a[:, 0])[0, 1]:+.2f}"
                      for k, name in ((1, "ε gated share"), (2, "samples learned"), (3, "states the filter kept"))))


if __name__ == "__main__":
    main(sys.argv[1:])
