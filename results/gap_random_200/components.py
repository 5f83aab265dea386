"""Which part of a parameter's standard deviation is too wide or too narrow: the random bench's cases
diagnosed again, with each component of the std kept (diagnosis.json `std_components`).

    python results/gap_random_200/components.py OUT_DIR [--jobs 2]

OUT_DIR is a `ciml gap-bench --random` folder whose cases kept their bags (case_NN/train_*,
heldout_*). A case whose own diagnosis (case_NN/diagnosis, from a bench run since `std_components`
exist) keeps the components is read as it is; the others are diagnosed again into
case_NN/diagnosis_components (skipped when it is there). Each is scored against its draw
(draws.json) by the bench's own score_case, and per effect type the script prints: coverage of the
68 % and 95 % intervals, the median |error|/std, and per component its median share of the variance
and the 68 % coverage the interval would have without it; then the coverage over all types if the
misspecification bound counted as another number of standard deviations (in sample: a choice made
from these cases must be checked on another draw: rescale.py scores a run at another scale, per
type, through the bench's own scoring).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from collections import defaultdict
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ciml_learning.core.robot import load_robot
from ciml_learning.diagnosis.uncertainty import MISSPECIFICATION_SCALE, Z68, Z95
from ciml_sim import gapbench


def diagnose(case: str) -> str:
    own = os.path.join(case, "diagnosis")
    if os.path.isfile(os.path.join(own, "diagnosis.json")):
        effects = json.load(open(os.path.join(own, "diagnosis.json"), encoding="utf-8")).get("effects") or []
        if all("std_components" in e for e in effects):
            return own
    out = os.path.join(case, "diagnosis_components")
    if not os.path.isfile(os.path.join(out, "diagnosis.json")):
        bags = sorted(os.listdir(case))
        train = [os.path.join(case, b) for b in bags if b.startswith("train_")]
        heldout = [os.path.join(case, b) for b in bags if b.startswith("heldout_")]
        ciml = os.path.join(os.path.dirname(sys.executable), "ciml")
        subprocess.run([ciml, "diagnose", "--bag", *train, "--heldout", *heldout, "--out", out],
                       check=True, capture_output=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out_dir")
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    specs = json.load(open(os.path.join(a.out_dir, "draws.json"), encoding="utf-8"))["cases"]
    cases = [(i, os.path.join(a.out_dir, f"case_{i:02d}")) for i in range(1, len(specs) + 1)]
    # finished cases (score.json written) that kept their bags
    cases = [(i, c) for i, c in cases
             if os.path.isdir(os.path.join(c, "train_0")) and os.path.isfile(os.path.join(c, "score.json"))]
    with ThreadPoolExecutor(a.jobs) as pool:
        dirs = list(pool.map(lambda ic: diagnose(ic[1]), cases))
    robot = load_robot()
    gapbench._LINKS.update(robot.link_names)
    by_type: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    for (i, _), d in zip(cases, dirs):
        diagnosis = json.load(open(os.path.join(d, "diagnosis.json"), encoding="utf-8"))
        for row in gapbench.score_case(specs[i - 1]["effects"], diagnosis, robot.joint_names)["effects"]:
            cov = row["coverage"]
            if not cov or "std_components" not in cov:
                continue
            acc = by_type[row["type"]]
            acc["error"] += cov["abs_error"]
            for name, v in cov["std_components"].items():
                acc[name] += v
    print(f"{len(cases)} cases\n")
    # the components as the diagnosis names them (identification.parameter_uncertainty), in its order
    names = list(dict.fromkeys(k for acc in by_type.values() for k in acc if k != "error"))
    print("| type | n | in 68 % | in 95 % | median abs(z) | " + " | ".join(
        f"{n}: var. share / 68 % without" for n in names) + " |")
    print("|---" * (5 + len(names)) + "|")
    total: dict[str, list] = defaultdict(list)
    for t, acc in sorted(by_type.items()):
        for k, v in acc.items():
            total[k] += v
        print(row_of(t, acc, names))
    print(row_of("all", total, names))
    # the misspecification bound counted as 1/scale standard deviations (uncertainty.py), in sample
    err = np.asarray(total["error"])
    rest = sum(np.asarray(total[n]) ** 2 for n in names if n != "misspecification")
    mis = np.asarray(total["misspecification"]) / MISSPECIFICATION_SCALE
    print("\n| misspecification scale | in 68 % | in 95 % |\n|---|---|---|")
    for scale in (0.25, 0.33, 0.4, 0.5, 0.75, 1.0):
        sd = np.sqrt(rest + (scale * mis) ** 2)
        print(f"| {scale:g} | {np.mean(err <= Z68 * sd):.0%} | {np.mean(err <= Z95 * sd):.0%} |")


def row_of(label: str, acc: dict, names: list[str]) -> str:
    err = np.asarray(acc["error"])
    parts = {n: np.asarray(acc[n]) for n in names}
    var = sum(p ** 2 for p in parts.values())
    sd = np.sqrt(var)
    z = np.where(sd > 0, err / np.where(sd > 0, sd, 1), np.inf)
    cells = []
    for n in names:
        share = np.median(np.where(var > 0, parts[n] ** 2 / np.where(var > 0, var, 1), 0))
        without = np.sqrt(np.maximum(var - parts[n] ** 2, 0))
        cells.append(f"{share:.2f} / {np.mean(err <= Z68 * without):.0%}")
    return (f"| {label} | {len(err)} | {np.mean(z <= Z68):.0%} | {np.mean(z <= Z95):.0%} | {np.median(z):.2f} | "
            + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
