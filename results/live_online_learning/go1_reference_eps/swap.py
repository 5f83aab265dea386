"""Does a model swap cost effort headless? go1_gap, trot_35 40 s, seed 11: model A until 20 s, model
B after (a model folder or `nominal`); RMS feedback effort [Nm] of 5 s windows from 10 s.

    python swap.py A B   → swap_output.txt
"""
import sys

import numpy as np

from ciml_learning.core.profile import load_profile, profile_path
from ciml_learning.learning.model_epsilon import load_epsilon_function
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

robot = load_profile(profile_path("go1")).robot()
scenario = resolve_scenario("go1_gap", robot)


def epsilon_of(folder: str):
    return (lambda ref: np.zeros(robot.nv)) if folder == "nominal" else load_epsilon_function(robot, folder)


a, b = epsilon_of(sys.argv[1]), epsilon_of(sys.argv[2])
run = run_headless(robot, scenario, "trot_35", 40.0, 11, epsilon_fn=lambda ref: (a if ref.t < 20.0 else b)(ref),
                   progress=False)
e = np.asarray(run.feedback_effort, float)
fs = len(e) / 40.0
w = [float(np.sqrt(np.mean(e[int(s * fs):int((s + 5) * fs)] ** 2))) for s in (10, 15, 20, 25, 30, 35)]
print(sys.argv[1].split("/")[-1], "->", sys.argv[2].split("/")[-1], "5 s windows from 10 s (switch at 20):",
      np.round(w, 3), f"after/before {w[2] / w[1]:.3f}", flush=True)
