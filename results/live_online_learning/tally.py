"""Ten-minute live runs of `ciml bench --only live_online_learning`, tallied across benchmark files.

    python results/live_online_learning/tally.py A.json B.json ...

Every run with learning in the files is compared, minute by minute, with the mean of the runs
without learning of its scenario in the same files (the baselines of one code version), by the
benchmark's own `live_bench.learning_summary`; prints, per scenario, one Markdown row per run
(seed, last-minute effort and cut, lowest cut from the second and from the third minute on, the
minute from which it stays ≥ 30 % below to the end, falls,
swaps, judged / unjudged, rolled back, the share of control steps with a gated ε entry in
minutes 2–5) and a summary line.
"""
from __future__ import annotations

import json
import sys

import numpy as np

from ciml_sim.live_bench import learning_summary


def runs(paths: list[str]) -> list[dict]:
    out = []
    for path in paths:
        bench = json.load(open(path, encoding="utf-8"))
        for run in bench["benchmarks"]["live_online_learning"]["runs"]:
            out.append({**run, "file": path, "commit": bench["machine"]["commit"][:7]})
    return out


def last(periods: list[dict], key: str) -> float:
    return float(periods[-1].get(key) or 0.0)


def gated_share(periods: list[dict], first: int, end: int) -> float:
    """Share of the controller's steps in minutes first..end (1-based) with an ε entry gated by
    the trust law (variance above the prior: the model does not know there)."""
    def at(k: int, key: str) -> float:
        return float(periods[k - 1].get(key) or 0.0) if k >= 1 else 0.0
    steps = at(end, "id_controller.commands") - at(first - 1, "id_controller.commands")
    gated = at(end, "id_controller.epsilon_gated") - at(first - 1, "id_controller.epsilon_gated")
    return gated / steps if steps else float("nan")


def main(paths: list[str]) -> None:
    all_runs = runs(paths)
    for scenario, summary in learning_summary(all_runs)["scenarios"].items():
        base = np.array([p["effort_without_nm"] for p in summary["per_period"]])
        minutes = summary["periods_compared"]
        these = [r for r in all_runs if r["scenario"] == scenario]
        print(f"## {scenario}\n\nbaselines: {', '.join(str(r['seed']) for r in these if not r['online'])}; "
              "per minute [Nm]: " + ", ".join(f"{b:.2f}" for b in base))
        print("\n| seed | commit | last minute [Nm] | last-minute cut | lowest cut, minutes 2–end | lowest cut, "
              "minutes 3–end | ≥ 30 % from minute (to the end) | fell | swaps | judged / unjudged | "
              "rolled back (worse than before) | ε gated, minutes 2–5 |\n"
              "|---|---|---|---|---|---|---|---|---|---|---|---|")
        online = [r for r in these if r["online"]]
        cuts = summary["last_period_cut_pct_per_run"]
        lowest2, held_from = [], []
        for r, last_cut in zip(online, cuts):
            effort = np.array([p["effort_rms_nm"] for p in r["periods"][:minutes]])
            cut = 100 * (1.0 - effort / base)
            lowest2.append(cut[1:].min())
            below = np.flatnonzero(cut < 30.0)  # held: every minute after the last one under 30 %
            held_from.append(int(below[-1]) + 2 if below.size else 1)
            p = r["periods"]
            held = held_from[-1] if held_from[-1] <= minutes else "—"
            print(f"| {r['seed']} | {r['commit']} | {effort[-1]:.2f} | {last_cut:.1f} % | {cut[1:].min():.1f} % | "
                  f"{cut[2:].min():.1f} % | {held} | {r.get('fell')} | {last(p, 'model_server.model_swaps'):.0f} | "
                  f"{last(p, 'id_controller.models_judged'):.0f} / {last(p, 'id_controller.models_unjudged'):.0f} | "
                  f"{last(p, 'id_controller.rollbacks_worse_than_before'):.0f} | {100 * gated_share(p, 2, 5):.0f} % |")
        print(f"\nruns with learning: {len(online)}; falls: {sum(bool(r.get('fell')) for r in these)} in "
              f"{len(these)} runs; last-minute cut ≥ 30 %: {sum(c >= 30.0 for c in cuts)} of {len(cuts)} "
              f"(range {min(cuts):.1f}–{max(cuts):.1f} %); every minute from the second ≥ 30 %: "
              f"{sum(c >= 30.0 for c in lowest2)} of {len(cuts)}; a minute from the second worse than "
              f"without learning: {sum(c < 0.0 for c in lowest2)}; ≥ 30 % held to the end from minute "
              f"{'/'.join(str(h) for h in held_from)}\n")


if __name__ == "__main__":
    main(sys.argv[1:])
