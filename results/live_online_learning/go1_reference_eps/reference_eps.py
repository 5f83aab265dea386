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

# the part of ε the contact forces cannot absorb: P_c ε, P_c = I − J_c⁺ J_c at the reference's
# stance feet (projection.projector); the learned model is identified only in that part
from ciml_learning.core.dynamics import RigidBodyDynamics  # noqa: E402
from ciml_learning.core.projection import contact_jacobian, projector  # noqa: E402

dyn = RigidBodyDynamics(robot)
num = den = num_raw = 0.0
rows, stance = [], []


def projected(ref):
    """ε from the model; P_c(learned − truth) and P_c truth accumulated at the reference."""
    global num, den, num_raw
    e_l, e_t = learned(ref), truth(ref)
    P = projector(contact_jacobian(dyn.foot_jacobians(np.asarray(ref.q, float)), np.asarray(ref.contacts, bool)))
    d, pt = P @ (e_l - e_t), P @ e_t
    num, den, num_raw = num + d @ d, den + pt @ pt, num_raw + (e_l - e_t) @ (e_l - e_t)
    rows.append(d)
    stance.append(np.asarray(ref.contacts, bool).copy())
    return e_l


print("learned, projected comparison", effort(projected))
print(f"explained of the truth's projected ε: 1 - |P(learned - truth)|² / |P truth|² = {1 - num / den:.3f} "
      f"(unprojected: |learned - truth|² / |P truth|² = {num_raw / den:.3f})")
D = np.array(rows)
print("rms of P(learned - truth):", " ".join(f"{n}={np.sqrt(np.mean(D[:, i] ** 2)):.3f}"
                                             for i, n in enumerate(robot.dof_names)))
C = np.array(stance)
for leg, foot in enumerate(robot.foot_frames):
    calf = [i for i, n in enumerate(robot.dof_names) if n.startswith(foot.split("_")[0]) and "calf" in n][0]
    in_stance, in_swing = (np.sqrt(np.mean(D[rows, calf] ** 2)) for rows in (C[:, leg], ~C[:, leg]))
    print(f"{robot.dof_names[calf]}: rms of P(learned - truth) in stance {in_stance:.3f}"
          f" ({C[:, leg].mean():.0%} of the references), in swing {in_swing:.3f}")
