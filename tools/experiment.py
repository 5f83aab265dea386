#!/usr/bin/env python3
"""The paper's experiment (Grandia et al. 2018, Tables I and II) in our simulation.

On the default gap scenario: record the training motions (base-only, walk 35 cm, trot
35 cm; several repetitions with different seeds), train LWPR and SGPR, then run the
controller with the nominal / LWPR / SGPR model on new executions of the training
motions (Table I) and on new motions (Table II), and evaluate the prediction RMSE per
dimension on the new motions (Fig. 4/5). Writes results/EXPERIMENT.md with the tables,
the figures (PNG), the command and the commit.

    .venv/bin/python tools/experiment.py [--out results] [--work out/experiment] [--quick]

Every number in the document comes from the `ciml` verbs run here (same code as users run).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CIML = os.path.join(os.path.dirname(sys.executable), "ciml")
SCENARIO = os.path.join(ROOT, "ciml_sim", "config", "scenarios", "default_gap.yaml")
TRAIN_MOTIONS = ("base_only", "walk_35", "trot_35")
NEW_MOTIONS = ("walk_20", "walk_30", "walk_rear_30", "walk_side_25", "trot_20", "trot_45")
MODELS = ("nominal", "lwpr", "sgpr")
METRICS = (("rms_feedback_effort_nm", "RMS ‖u_fb‖ [Nm]"), ("rms_attitude_error_deg", "RMS attitude [deg]"),
           ("rms_base_position_error_mm", "RMS base pos. [mm]"), ("rms_joint_error_deg", "RMS joint [deg]"))


def ciml(*args: str) -> None:
    print("$ ciml " + " ".join(args), flush=True)
    subprocess.run([CIML, *args], check=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default=os.path.join(ROOT, "results"))
    p.add_argument("--work", default=os.path.join(ROOT, "out", "experiment"))
    p.add_argument("--repetitions", type=int, default=3, help="training recordings per motion")
    p.add_argument("--duration", type=float, default=20.0, help="seconds per training recording")
    p.add_argument("--eval-duration", type=float, default=None, help="closed-loop seconds (default: 10 gait cycles)")
    p.add_argument("--quick", action="store_true", help="1 repetition of 8 s, 6 s closed loops (a smoke run)")
    args = p.parse_args()
    if args.quick:
        args.repetitions, args.duration, args.eval_duration = 1, 8.0, 6.0
    os.makedirs(args.work, exist_ok=True)
    t_start = time.time()
    args.commit = _commit()

    bags = []
    for motion in TRAIN_MOTIONS:
        for rep in range(args.repetitions):
            bag = os.path.join(args.work, "bags", f"{motion}_{rep}")
            if not os.path.isdir(bag):
                ciml("record", "--scenario", SCENARIO, "--motion", motion, "--duration", str(args.duration),
                     "--seed", str(1 + rep), "--no-ground-truth", "--out", bag)
            bags.append(bag)
    heldout = []
    for motion in NEW_MOTIONS:
        bag = os.path.join(args.work, "bags", f"new_{motion}")
        if not os.path.isdir(bag):
            ciml("record", "--scenario", SCENARIO, "--motion", motion, "--duration", str(min(args.duration, 12.0)),
                 "--seed", "77", "--no-ground-truth", "--out", bag)
        heldout.append(bag)

    train_s = {}
    for learner in ("lwpr", "sgpr"):
        model = os.path.join(args.work, f"model_{learner}")
        t0 = time.perf_counter()
        ciml("train", "--bag", *bags, "--learner", learner, "--out", model)
        train_s[learner] = time.perf_counter() - t0
        ciml("evaluate", "--model", model, "--bag", *heldout,
             "--out", os.path.join(args.work, f"evaluate_{learner}.json"))

    results: dict[str, dict[str, dict]] = {}
    for motion in TRAIN_MOTIONS + NEW_MOTIONS:
        for model in MODELS:
            out = os.path.join(args.work, "closed_loop", f"{motion}_{model}.json")
            if not os.path.exists(out):
                extra = ["--duration", str(args.eval_duration)] if args.eval_duration else []
                ciml("closed-loop", "--scenario", SCENARIO, "--motion", motion, "--seed", "1001",
                     "--model", "nominal" if model == "nominal" else os.path.join(args.work, f"model_{model}"),
                     "--out", out, *extra)
            with open(out, encoding="utf-8") as f:
                results.setdefault(motion, {})[model] = json.load(f)

    os.makedirs(args.out, exist_ok=True)
    figures = plot_rmse(args.work, args.out)
    write_document(args, results, train_s, figures, bags, time.time() - t_start)
    return 0


def _metric(result: dict, key: str) -> float:
    return float(result.get("metrics", result).get(key, float("nan")))


def table(results: dict, motions: tuple[str, ...]) -> str:
    head = "| motion | metric | nominal | LWPR | SGPR | best reduction |\n|---|---|---|---|---|---|"
    rows = [head]
    for motion in motions:
        for key, label in METRICS:
            vals = [_metric(results[motion][m], key) for m in MODELS]
            best = min(vals[1:])
            red = 100 * (1 - best / vals[0]) if vals[0] > 0 else float("nan")
            rows.append(f"| {motion} | {label} | {vals[0]:.2f} | {vals[1]:.2f} | {vals[2]:.2f} | {red:.0f} % |")
        falls = [m for m in MODELS if results[motion][m].get("metrics", results[motion][m]).get("fell")]
        if falls:
            rows.append(f"| {motion} | fell | {', '.join(falls)} | | | |")
    return "\n".join(rows)


def mean_reduction(results: dict, motions: tuple[str, ...], model: str, key: str = "rms_feedback_effort_nm") -> float:
    import numpy as np

    return float(np.mean([1 - _metric(results[m][model], key) / _metric(results[m]["nominal"], key) for m in motions]))


def plot_rmse(work: str, out: str) -> list[str]:
    """Per-dimension prediction RMSE on the new motions, nominal (zero) vs learned (paper Fig. 4/5)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    evals = {}
    for learner in ("lwpr", "sgpr"):
        with open(os.path.join(work, f"evaluate_{learner}.json"), encoding="utf-8") as f:
            evals[learner] = json.load(f)
    figures = []
    for group in ("rbd", "actuation"):
        by_learner = {lr: {d["name"]: d for d in evals[lr]["dimensions"] if d["kind"] == group and d["samples"]}
                      for lr in evals}
        names = list(by_learner["sgpr"])
        nominal = [by_learner["sgpr"][n]["rmse_nominal"] for n in names]
        fig, ax = plt.subplots(figsize=(11, 3.5))
        x = np.arange(len(names))
        ax.bar(x - 0.27, nominal, 0.27, label="nominal")
        for k, learner in enumerate(("lwpr", "sgpr")):
            ax.bar(x + k * 0.27, [by_learner[learner][n]["rmse_learned"] for n in names], 0.27, label=learner.upper())
        ax.set_xticks(x, names, rotation=60, ha="right", fontsize=8)
        ax.set_ylabel("RMSE [N, Nm]")
        ax.set_title(f"{group} error prediction on new motions")
        ax.legend()
        fig.tight_layout()
        path = os.path.join(out, f"experiment_rmse_{group}.png")
        fig.savefig(path, dpi=110)
        plt.close(fig)
        figures.append(os.path.basename(path))
    return figures


def _commit() -> str:
    """HEAD at the start of the run, marked when the tracked sources differ from it."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                            cwd=ROOT).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], capture_output=True, text=True,
                           cwd=ROOT).stdout.strip()
    return f"`{commit}`" + (" (with uncommitted changes)" if dirty else "")


def write_document(args, results, train_s, figures, bags, wall_s) -> None:
    cmd = "python tools/experiment.py " + " ".join(sys.argv[1:])
    lines = [
        "# The paper's experiment in simulation (Tables I and II)",
        "",
        f"Produced by `{cmd.strip()}`, started at commit {args.commit}, "
        f"on {time.strftime('%Y-%m-%d')}, {wall_s / 60:.0f} min on this 2-core machine.",
        f"Scenario: `ciml_sim/config/scenarios/default_gap.yaml`; {len(bags)} training recordings "
        f"({args.repetitions} per motion, {args.duration:g} s each). Training time: "
        + ", ".join(f"{k.upper()} {v:.0f} s" for k, v in train_s.items()) + ".",
        "",
        "## Table I — new executions of the training motions",
        "",
        table(results, TRAIN_MOTIONS),
        "",
        "## Table II — new motions",
        "",
        table(results, NEW_MOTIONS),
        "",
        "## Feedback-effort reduction vs nominal (mean over motions)",
        "",
        "| model | training motions | new motions |",
        "|---|---|---|",
    ]
    for model in ("lwpr", "sgpr"):
        lines.append(f"| {model.upper()} | {100 * mean_reduction(results, TRAIN_MOTIONS, model):.1f} % "
                     f"| {100 * mean_reduction(results, NEW_MOTIONS, model):.1f} % |")
    lines += ["", "## Prediction RMSE per dimension on new motions", "",
              "| model | base dims learned < nominal | actuators learned < nominal "
              "| RMSE reduction (rbd / actuation) |",
              "|---|---|---|---|"]
    for learner in ("lwpr", "sgpr"):
        with open(os.path.join(args.work, f"evaluate_{learner}.json"), encoding="utf-8") as f:
            ev = json.load(f)
        dims = [d for d in ev["dimensions"] if d["samples"]]
        base = [d for d in dims if d["name"].startswith("base_")]
        act = [d for d in dims if d["kind"] == "actuation"]

        def better(ds):
            return f"{sum(d['rmse_learned'] < d['rmse_nominal'] for d in ds)} / {len(ds)}"

        red = ev["summary"]
        lines.append(f"| {learner.upper()} | {better(base)} | {better(act)} | "
                     f"{100 * red['rbd'].get('reduction', float('nan')):.0f} % / "
                     f"{100 * red['actuation'].get('reduction', float('nan')):.0f} % |")
    lines.append("")
    lines += [f"![{f}]({f})" for f in figures]
    path = os.path.join(args.out, "EXPERIMENT.md")
    with open(path + ".tmp", "w", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    os.replace(path + ".tmp", path)
    print(f"experiment: {path}")


if __name__ == "__main__":
    sys.exit(main())
