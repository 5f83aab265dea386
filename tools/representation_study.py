"""Study: which learned representation of the model error generalises to new gaits (issue 6).

Not a product path: it trains the product's LWPR model set (models.py, format 3: joint-space leg
errors, the base wrench after them from the base's state) and, with `--actuation-inputs torque`,
actuation models the ModelSet does not offer yet, and runs the closed loop with them.

--actuation-inputs
    joint: Γ from (q, q̇, q̈) of the joint, as ModelSet does; torque: also τ and τ̇, measured in
    training and the reference's (dynamics.ReferenceTorque) in the loop — lag and gain are
    functions of the torque.

    python tools/representation_study.py --bags out/experiment/bags --actuation-inputs torque \\
        --motions walk_35,walk_side_25
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from ciml_control.references import default_duration
from ciml_learning.dynamics import ReferenceTorque, selection_matrix
from ciml_learning.extraction import actuation_inputs, learning_inputs
from ciml_learning.learners.lwpr import LWPR
from ciml_learning.models import DEFAULT_PARAMS, ModelSet
from ciml_learning.pipeline import load_dataset
from ciml_learning.robot import load_robot
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

TRAINING = ("base_only", "walk_35", "trot_35")


def fit_models(robot, ds, actuation: str):
    tg = ds.targets
    gamma = np.full_like(tg.actuation_error, np.nan) if actuation == "torque" else tg.actuation_error
    ms = ModelSet.for_robot(robot, "lwpr").fit(tg.inputs, tg.generalized_error, tg.generalized_observed, gamma,
                                               tg.valid, tg.leg_coupling)
    torque_models = []
    if actuation == "torque":
        for j in range(robot.n_joints):
            X = np.column_stack([actuation_inputs(ds.log.q, ds.log.v, ds.log.a, j), ds.log.tau[:, j], ds.log.tau_dot[:, j]])
            rows = tg.valid & np.isfinite(tg.actuation_error[:, j])
            mean, std = X[rows].mean(0), X[rows].std(0) + 1e-9
            y = tg.actuation_error[rows, j]
            scale = float(np.sqrt(np.mean(y ** 2)))
            model = LWPR(**DEFAULT_PARAMS["lwpr"]["actuation"]).fit((X[rows] - mean) / std, y / scale)
            torque_models.append((model, mean, std, scale))
    return ms, torque_models


class StudyEpsilon:
    """ε at a reference point for a representation of fit_models."""

    def __init__(self, robot, ms: ModelSet, torque_models) -> None:
        self.robot, self.ms, self.torque_models = robot, ms, torque_models
        self.S = selection_matrix(robot)
        self.reference_torque = ReferenceTorque(robot)

    def __call__(self, ref) -> np.ndarray:
        rbd, _, gamma, _ = self.ms.predict_one(learning_inputs(ref.q, ref.v, ref.a)[0])
        if self.torque_models:
            tau, tau_dot = self.reference_torque(ref, rbd)
            for j, (model, mean, std, scale) in enumerate(self.torque_models):
                x = np.array([ref.q[7 + j], ref.v[6 + j], ref.a[6 + j], tau[j], tau_dot[j]])
                gamma[j] = model.predict_one((x - mean) / std)[0] * scale
        eps = rbd - self.S.T @ gamma  # eq. (17): the set learns J'ᵀΦ̃' directly
        return eps if np.all(np.isfinite(eps)) else np.zeros(self.robot.nv)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bags", required=True, help="directory with base_only_0..2, walk_35_0..2, trot_35_0..2")
    ap.add_argument("--actuation-inputs", choices=("joint", "torque"), default="joint")
    ap.add_argument("--motions", default="walk_35,walk_rear_30,walk_side_25,trot_20")
    ap.add_argument("--scenario", default="ciml_sim/config/scenarios/default_gap.yaml")
    ap.add_argument("--seed", type=int, default=1001)
    args = ap.parse_args()
    robot = load_robot()
    ds = load_dataset(robot, [f"{args.bags}/{m}_{r}" for m in TRAINING for r in range(3)], progress=False)
    t0 = time.perf_counter()
    ms, torque_models = fit_models(robot, ds, args.actuation_inputs)
    fit_s = time.perf_counter() - t0
    scenario = resolve_scenario(args.scenario, robot)
    eps = StudyEpsilon(robot, ms, torque_models)
    effort = {}
    for motion in args.motions.split(","):
        run = run_headless(robot, scenario, motion, default_duration(motion), seed=args.seed, epsilon_fn=eps,
                           progress=False)
        effort[motion] = round(run.metrics()["rms_feedback_effort_nm"], 2)
    print(json.dumps({"actuation_inputs": args.actuation_inputs,
                      "fit_s": round(fit_s, 1), "rms_feedback_effort_nm": effort}))


if __name__ == "__main__":
    main()
