"""The headless closed loop (go1_gap or default_gap, trot_35, seed 42) with the reference sampled at
t + DELTA after the first 2 s: DELTA = ±1e-12 s puts every sample at a pair switch on one side of it
(before the fix the branch of the trot's lateral sway, whose ÿ jumps there, followed the rounding of
t). RMS feedback effort [Nm] per 10 s.

    python headless_shift.py ROBOT MODEL DELTA DURATION     (MODEL: nominal or a model directory)
→ output.txt (run in a worktree of the revision before the fix, and at the fix)
"""
import sys

import numpy as np

import ciml_sim.recorder as recorder
from ciml_learning.core.profile import load_profile, profile_path
from ciml_learning.learning.model_epsilon import EpsilonFunction
from ciml_learning.learning.models import ModelSet
from ciml_sim.scenario import resolve_scenario

robot_name, model, delta, duration = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
robot = load_profile(profile_path(robot_name)).robot()
make_reference = recorder.make_reference


def shifted(*args):
    reference = make_reference(*args)
    sample = reference.sample
    reference.sample = lambda t: sample(t + delta if t > 2.0 else t)
    return reference


recorder.make_reference = shifted
eps = None if model == "nominal" else EpsilonFunction(robot, ModelSet.load(model, robot))
scenario = "go1_gap" if robot_name == "go1" else "default_gap"
run = recorder.run_headless(robot, resolve_scenario(scenario, robot), "trot_35", duration, 42, epsilon_fn=eps,
                            progress=False)
e = np.asarray(run.feedback_effort)
fs = len(e) / duration
print(robot_name, model.rstrip("/").split("/")[-1], "delta", delta, "RMS effort per 10 s",
      [round(float(np.sqrt(np.mean(e[int(a * fs):int((a + 10) * fs)] ** 2))), 3) for a in range(0, int(duration), 10)],
      flush=True)
