"""go1_gap headless: the learned model's rigid-body part and actuation part (Γ) against the true
effects' (payload + calf friction; actuator lag), alone and mixed.

    python parts.py MODEL_DIR TRUTH_DIR   # TRUTH_DIR/diagnosis.json = go1_gap_true_effects.json

Closed loop trot_35, 30 s, seed 11, RMS feedback effort [Nm]; then, along the learned run's
references, how much of each true part's projected ε (P_c ε, the part the contact forces cannot
absorb) the learned part explains, and the calves' entries of each.
"""
import json
import os
import sys
import tempfile

import numpy as np

from ciml_learning.core.dynamics import RigidBodyDynamics
from ciml_learning.core.extraction import combined_error
from ciml_learning.core.profile import load_profile
from ciml_learning.core.projection import contact_jacobian, projector
from ciml_learning.learning.model_epsilon import load_epsilon_function
from ciml_sim.commands import load_epsilon_function as load_any
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

HERE = os.path.dirname(os.path.abspath(__file__))
robot = load_profile(os.path.join(HERE, "..", "go1_ciml_topics_profile.yaml")).robot()
scenario = resolve_scenario("go1_gap", robot)
learned = load_epsilon_function(robot, sys.argv[1])
S = learned._S
truth_model = json.load(open(os.path.join(sys.argv[2], "diagnosis.json")))
tmp = tempfile.mkdtemp()
true_part = {}
for part, keep in (("lag", lambda e: e["type"] == "actuator_lag"), ("rbd", lambda e: e["type"] != "actuator_lag")):
    os.makedirs(os.path.join(tmp, part))
    effects = [e for e in truth_model["model"]["effects"] if keep(e)]
    with open(os.path.join(tmp, part, "diagnosis.json"), "w") as f:
        json.dump({"model": dict(truth_model["model"], effects=effects), "description": part}, f)
    true_part[part] = load_any(robot, os.path.join(tmp, part))


def learned_parts(ref):
    rbd, _, gamma, _ = learned.predict(ref)
    return combined_error(None, rbd, np.zeros_like(gamma), S), combined_error(None, np.zeros_like(rbd), gamma, S)


def effort(fn):
    return round(run_headless(robot, scenario, "trot_35", 30.0, 11, epsilon_fn=fn,
                              progress=False).metrics()["rms_feedback_effort_nm"], 3)


print("true lag only", effort(true_part["lag"]), "| true rigid body only", effort(true_part["rbd"]),
      "| learned rigid body only", effort(lambda r: learned_parts(r)[0]),
      "| learned rigid body + true lag", effort(lambda r: learned_parts(r)[0] + true_part["lag"](r)),
      "| true rigid body + learned Γ", effort(lambda r: true_part["rbd"](r) + learned_parts(r)[1]))
dyn = RigidBodyDynamics(robot)
calves = [i for i, n in enumerate(robot.dof_names) if "calf" in n]
acc = {k: [0.0, 0.0, [], []] for k in ("rbd", "lag")}


def compare(ref):
    parts = dict(zip(("rbd", "lag"), learned_parts(ref)))
    P = projector(contact_jacobian(dyn.foot_jacobians(np.asarray(ref.q, float)), np.asarray(ref.contacts, bool)))
    for k, a in acc.items():
        pl, pt = P @ parts[k], P @ true_part[k](ref)
        a[0] += (pl - pt) @ (pl - pt)
        a[1] += pt @ pt
        a[2].append(pl[calves])
        a[3].append(pt[calves])
    return parts["rbd"] + parts["lag"]


print("learned (compared)", effort(compare))
for k, (num, den, L, T) in acc.items():
    L, T = np.array(L), np.array(T)
    print(f"{k}: explained of the true part's projected ε {1 - num / den:.3f}; calves rms learned "
          f"{np.sqrt((L ** 2).mean(0)).round(3)} true {np.sqrt((T ** 2).mean(0)).round(3)} corr "
          f"{[round(float(np.corrcoef(L[:, j], T[:, j])[0, 1]), 3) for j in range(len(calves))]}")
