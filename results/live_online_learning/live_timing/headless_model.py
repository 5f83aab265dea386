"""One snapshot in the headless loop (go1_gap, trot_35): RMS feedback effort [Nm] per minute, with
some outputs removed (their ε = 0) or with ε one 4 ms tick late in a share of the ticks.

    python headless_model.py SNAPSHOT DURATION SEED [--drop I ...] [--late P]   → output.txt
"""
import argparse

import numpy as np

from ciml_learning.core.profile import load_profile, profile_path
from ciml_learning.learning.model_epsilon import EpsilonFunction
from ciml_learning.learning.models import ModelSet
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

parser = argparse.ArgumentParser()
parser.add_argument("snapshot")
parser.add_argument("duration", type=float)
parser.add_argument("seed", type=int)
parser.add_argument("--drop", type=int, nargs="*", default=[], help="output dimensions removed")
parser.add_argument("--late", type=float, default=0.0, help="share of ticks given the previous tick's ε")
args = parser.parse_args()
robot = load_profile(profile_path("go1")).robot()
ms = ModelSet.load(args.snapshot, robot)
for i in args.drop:
    ms.models_[i] = None
on_time = EpsilonFunction(robot, ms)
rng = np.random.default_rng(1)
last: list = [None]


def epsilon(ref) -> np.ndarray:
    e = on_time(ref)
    out = last[0] if last[0] is not None and rng.random() < args.late else e
    last[0] = e
    return out


run = run_headless(robot, resolve_scenario("go1_gap", robot), "trot_35", args.duration, args.seed,
                   epsilon_fn=epsilon, progress=False)
e = np.asarray(run.feedback_effort, float)
fs = len(e) / args.duration
minutes = [float(np.sqrt(np.mean(e[int(a * fs):int((a + 60) * fs)] ** 2))) for a in range(0, int(args.duration), 60)]
print(args.snapshot.rstrip("/").split("/")[-1], "drop", args.drop, "late", args.late, "seed", args.seed,
      "RMS effort per minute", np.round(minutes, 3).tolist(), flush=True)
