"""go1_gap: the calves' actuation-model inputs it learned from against those a reference gives it.

    python gamma_inputs.py MODEL_DIR TRAINING_BAG   # the model of reference_eps.py, the bag it learned from

Along a closed loop (trot_35, 30 s, seed 11, the learned model in the loop without its variance
gate), each reference's actuation inputs (q, q̇, q̈, τ_ref, τ̇_ref; model_epsilon.EpsilonFunction)
are logged; per calf it prints their mean and std beside those of the training rows, and the
model's slope ∂Γ/∂τ̇ (finite difference, +10 Nm/s) at both (the true lag: −T = −0.01 s).
"""
import os
import sys

import numpy as np

from ciml_learning.core.profile import load_profile
from ciml_learning.learning.model_epsilon import load_epsilon_function
from ciml_learning.logs.pipeline import load_dataset
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

HERE = os.path.dirname(os.path.abspath(__file__))
profile = load_profile(os.path.join(HERE, "..", "go1_ciml_topics_profile.yaml"))
robot = profile.robot()
learned = load_epsilon_function(robot, sys.argv[1])
ms = learned.model_set
at_reference = []
predict = ms.predict_part_one


def logged(x, part):
    if part == "actuation":
        at_reference.append(x.copy())
    return predict(x, part)


ms.predict_part_one = logged
run_headless(robot, resolve_scenario("go1_gap", robot), "trot_35", 30.0, 11, epsilon_fn=lambda r: learned(r),
             progress=False)
ms.predict_part_one = predict
R = np.array(at_reference)
tg = load_dataset(robot, [sys.argv[2]], progress=False, profile=profile).targets
T = tg.inputs[tg.valid]
index = {n: i for i, n in enumerate(ms.input_names)}


def slope(X, j, rate):
    X = X[:: max(1, len(X) // 1500)]
    up = X.copy()
    up[:, rate] += 10.0
    return float(np.median([(predict(b, "actuation")[0][j] - predict(a, "actuation")[0][j]) / 10.0
                            for a, b in zip(X, up)]))


print(f"training rows (valid) {len(T)} of {len(tg.valid)}; references {len(R)}")
for j, joint in enumerate(robot.joint_names):
    if "calf" not in joint:
        continue
    print(joint)
    for name in ms.input_names:
        if name.endswith(joint):
            a, b = T[:, index[name]], R[:, index[name]]
            print(f"  {name:>22}: training mean {a.mean():8.2f} std {a.std():7.2f} | references mean "
                  f"{b.mean():8.2f} std {b.std():7.2f}")
    rate = index[f"taud_{joint}"]
    print(f"  dΓ/dτ̇: at the training rows {slope(T, j, rate):.4f} s, at the references {slope(R, j, rate):.4f} s")
