"""go1_gap headless: where a learned model's ε at the reference stands against the true effects'.

    python reference_eps.py MODEL_DIR TRUTH_DIR   # TRUTH_DIR holds go1_gap_true_effects.json as diagnosis.json

Closed loop trot_35, 30 s, seed 11 (RMS feedback effort [Nm]) with: the nominal model, the learned
model through the trust law, the same without its variance gate (clip only), the true effects; then,
along the learned run's references, each generalized coordinate's ε from the model and from the truth.
"""
import os
import sys

import numpy as np

from ciml_learning.core.profile import load_profile
from ciml_learning.learning.model_epsilon import load_epsilon_function
from ciml_sim.commands import load_epsilon_function as load_any
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

HERE = os.path.dirname(os.path.abspath(__file__))
robot = load_profile(os.path.join(HERE, "..", "go1_ciml_topics_profile.yaml")).robot()
scenario = resolve_scenario("go1_gap", robot)
learned = load_epsilon_function(robot, sys.argv[1])
truth = load_any(robot, sys.argv[2])


def effort(fn):
    r = run_headless(robot, scenario, "trot_35", 30.0, 11, epsilon_fn=fn, progress=False)
    return round(r.metrics()["rms_feedback_effort_nm"], 3), getattr(r, "epsilon_trust", {})


print("nominal", effort(None))
print("learned, trust law", effort(learned))
print("learned, clip only", effort(lambda ref: learned(ref)))
print("true effects", effort(truth))
pairs = []


def logged(ref):
    e = learned(ref)
    pairs.append((e, truth(ref)))
    return e


print("learned, logged", effort(logged))
L, T = (np.array(z) for z in zip(*pairs))
for i, name in enumerate(robot.dof_names):
    print(f"{name:>16}  rms truth {np.sqrt(np.mean(T[:, i] ** 2)):7.3f}  mean truth {T[:, i].mean():7.3f}  "
          f"rms learned {np.sqrt(np.mean(L[:, i] ** 2)):7.3f}  mean learned {L[:, i].mean():7.3f}")
