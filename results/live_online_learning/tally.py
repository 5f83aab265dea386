"""Ten-minute live runs of `ciml bench --only live_online_learning`, tallied across benchmark files.

    python results/live_online_learning/tally.py A.json B.json ...

Every run with learning in the files is compared, minute by minute, with the mean of the runs
without learning in the same files (the baselines of one code version); prints one Markdown row
per run (seed, last-minute effort and cut, worst minute from the third on, falls, swaps,
judged / unjudged, rolled back) and a summary line.
"""
from __future__ import annotations

import json
import sys

import numpy as np


def runs(paths: list[str]) -> list[dict]:
    out = []
    for path in paths:
        bench = json.load(open(path, encoding="utf-8"))
        for run in bench["benchmarks"]["live_online_learning"]["runs"]:
            out.append({**run, "file": path, "commit": bench["machine"]["commit"][:7]})
    return out


def last(periods: list[dict], key: str) -> float:
    return float(periods[-1].get(key) or 0.0)


def main(paths: list[str]) -> None:
    all_runs = runs(paths)
    baselines = [r for r in all_runs if not r["online"]]
    minutes = min(len(r["periods"]) for r in all_runs)
    base = np.mean([[p["effort_rms_nm"] for p in r["periods"][:minutes]] for r in baselines], axis=0)
    print(f"baselines: {', '.join(str(r['seed']) for r in baselines)}; per minute [Nm]: "
          + ", ".join(f"{b:.2f}" for b in base))
    print("\n| seed | commit | last minute [Nm] | last-minute cut | lowest cut, minutes 3–end | fell | swaps | "
          "judged / unjudged | rolled back (worse than before) |\n|---|---|---|---|---|---|---|---|---|")
    cuts = []
    for r in (r for r in all_runs if r["online"]):
        effort = np.array([p["effort_rms_nm"] for p in r["periods"][:minutes]])
        cut = 1.0 - effort / base
        cuts.append(cut[-1])
        p = r["periods"]
        print(f"| {r['seed']} | {r['commit']} | {effort[-1]:.2f} | {100 * cut[-1]:.1f} % | "
              f"{100 * cut[2:].min():.1f} % | "
              f"{r.get('fell')} | {last(p, 'model_server.model_swaps'):.0f} | "
              f"{last(p, 'id_controller.models_judged'):.0f} / {last(p, 'id_controller.models_unjudged'):.0f} | "
              f"{last(p, 'id_controller.rollbacks_worse_than_before'):.0f} |")
    online = [r for r in all_runs if r["online"]]
    print(f"\nruns with learning: {len(online)}; falls: {sum(bool(r.get('fell')) for r in all_runs)} in "
          f"{len(all_runs)} runs; last-minute cut ≥ 30 %: {sum(c >= 0.30 for c in cuts)} of {len(cuts)} "
          f"(range {100 * min(cuts):.1f}–{100 * max(cuts):.1f} %)")


if __name__ == "__main__":
    main(sys.argv[1:])
