"""Study: which learned representation of the model error generalises to new gaits (issue 6).

Not a product path: it trains LWPR models in representations the ModelSet does not offer yet
and runs the closed loop with them, to decide what the next model format should learn.

Representations (the current format is `--legs feet --base-inputs all --actuation-inputs joint`):

--legs feet     a foot's three Φ̃' entries (eq. 11, foot force, world-aligned), as ModelSet does.
--legs joints   each leg joint's rigid-body error e = B_iᵀ φ_i (B_i: the leg block of the foot
                Jacobian; observed while the leg swings), from that joint's own q, q̇, q̈; and the
                base entries learned after the legs: w = w' + Σ_i C_i ẽ_i with C_i = J_i,baseᵀ B_i⁻ᵀ,
                ẽ_i the measured e for swinging legs and the learned one for stance legs (a stance
                leg's joint error otherwise shows in w' through the contact-invariant basis, as a
                function of every leg's state). ε = [w; e] − SᵀΓ.
--base-inputs   all 50 inputs of eq. (12), or only the base's (roll, pitch, q̇_base, q̈_base).
--actuation-inputs
                joint: (q, q̇, q̈) of the joint, as ModelSet does; torque: also τ and τ̇, measured in
                training and the reference's (dynamics.ReferenceTorque) in the loop — lag and gain
                are functions of the torque.

    python tools/representation_study.py --bags out/experiment/bags --legs joints \\
        --base-inputs base --actuation-inputs torque --motions walk_35,walk_side_25
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from ciml_control.references import default_duration
from ciml_learning.dynamics import ReferenceTorque, RigidBodyDynamics, selection_matrix
from ciml_learning.extraction import actuation_inputs, dynamics_batch, learning_input_names, learning_inputs
from ciml_learning.learners.lwpr import LWPR
from ciml_learning.models import DEFAULT_PARAMS, ModelSet
from ciml_learning.pipeline import load_dataset
from ciml_learning.projection import contact_invariant_basis, contact_invariant_bases
from ciml_learning.robot import load_robot
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

TRAINING = ("base_only", "walk_35", "trot_35")


def leg_blocks(robot, ds) -> tuple[np.ndarray, np.ndarray]:
    """B_i (N × n_feet × 3 × 3) and the base columns J_i,base (N × n_feet × 3 × 6) of J'.

    A second Pinocchio pass over the log (the extraction keeps no Jacobians: 216 floats a sample)."""
    _, jac = dynamics_batch(robot, ds.log.q, ds.log.v, ds.log.a)
    basis = contact_invariant_bases(jac, robot.leg_joints)
    n = len(basis)
    B = np.zeros((n, robot.n_feet, 3, 3))
    Jb = np.zeros((n, robot.n_feet, 3, 6))
    for f, leg in enumerate(robot.leg_joints):
        rows = slice(6 + 3 * f, 9 + 3 * f)
        B[:, f] = basis[:, rows][:, :, 6 + np.asarray(leg)]
        Jb[:, f] = basis[:, rows, :6]
    return B, Jb


def fit_models(robot, ds, legs: str, base_inputs: str, actuation: str):
    tg = ds.targets
    P = DEFAULT_PARAMS["lwpr"]
    names = learning_input_names(robot)
    base_cols = np.array([i for i, n in enumerate(names)
                          if n in ("base_roll", "base_pitch") or n.startswith(("qd_base", "qdd_base"))])
    rbd = tg.rbd_error.copy()
    none = np.full_like(tg.actuation_error, np.nan)  # targets that give no models
    if legs == "joints":
        B, Jb = leg_blocks(robot, ds)
        for f in range(robot.n_feet):
            rbd[:, 6 + 3 * f:9 + 3 * f] = np.einsum("nji,nj->ni", B[:, f], tg.rbd_error[:, 6 + 3 * f:9 + 3 * f])

    def model_set():
        ms = ModelSet.for_robot(robot, "lwpr", P["rbd"], P["actuation"], foot_params=P["foot"])
        if base_inputs == "base":
            for d in range(6):
                ms.input_index[d] = base_cols
        if legs == "joints":
            for j, joint in enumerate(robot.joint_names):
                ms.input_index[6 + j] = np.array([names.index(n) for n in (f"q_{joint}", f"qd_{joint}", f"qdd_{joint}")])
        return ms

    if legs == "joints":
        # the legs first (base rows unobserved, no actuation targets: only leg models in this pass),
        # then the base target with the stance legs' learned joint errors
        legs_only = tg.rbd_observed.copy()
        legs_only[:, :6] = False
        ms = model_set().fit(tg.inputs, rbd, legs_only, none, tg.valid)
        e_tilde = np.where(tg.rbd_observed[:, 6:], rbd[:, 6:], ms.predict(tg.inputs, return_var=False).rbd[:, 6:])
        for f in range(robot.n_feet):
            force = np.linalg.solve(np.transpose(B[:, f], (0, 2, 1)), e_tilde[:, 3 * f:3 * f + 3, None])[..., 0]
            rbd[:, :6] += np.einsum("nji,nj->ni", Jb[:, f], force)
    ms = model_set().fit(tg.inputs, rbd, tg.rbd_observed, none if actuation == "torque" else tg.actuation_error,
                         tg.valid)
    torque_models = []
    if actuation == "torque":
        for j in range(robot.n_joints):
            X = np.column_stack([actuation_inputs(ds.log.q, ds.log.v, ds.log.a, j), ds.log.tau[:, j], ds.log.tau_dot[:, j]])
            rows = tg.valid & np.isfinite(tg.actuation_error[:, j])
            mean, std = X[rows].mean(0), X[rows].std(0) + 1e-9
            y = tg.actuation_error[rows, j]
            scale = float(np.sqrt(np.mean(y ** 2)))
            torque_models.append((LWPR(**P["actuation"]).fit((X[rows] - mean) / std, y / scale), mean, std, scale))
    return ms, torque_models


class StudyEpsilon:
    """ε at a reference point for a representation of fit_models."""

    def __init__(self, robot, ms: ModelSet, torque_models, legs: str) -> None:
        self.robot, self.ms, self.torque_models, self.legs = robot, ms, torque_models, legs
        self.S = selection_matrix(robot)
        self.dyn = RigidBodyDynamics(robot)
        self.reference_torque = ReferenceTorque(robot)

    def __call__(self, ref) -> np.ndarray:
        phi, _, gamma, _ = self.ms.predict_one(learning_inputs(ref.q, ref.v, ref.a)[0])
        if self.legs == "joints":
            rbd = phi  # already generalized forces: [w; e]
        else:
            rbd = contact_invariant_basis(self.dyn.foot_jacobians(ref.q), self.robot.leg_joints).T @ phi
        if self.torque_models:
            tau, tau_dot = self.reference_torque(ref, rbd)
            for j, (model, mean, std, scale) in enumerate(self.torque_models):
                x = np.array([ref.q[7 + j], ref.v[6 + j], ref.a[6 + j], tau[j], tau_dot[j]])
                gamma[j] = model.predict_one((x - mean) / std)[0] * scale
        eps = rbd - self.S.T @ gamma  # eq. (17), J'ᵀΦ̃' already applied
        return eps if np.all(np.isfinite(eps)) else np.zeros(self.robot.nv)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bags", required=True, help="directory with base_only_0..2, walk_35_0..2, trot_35_0..2")
    ap.add_argument("--legs", choices=("feet", "joints"), default="feet")
    ap.add_argument("--base-inputs", choices=("all", "base"), default="all")
    ap.add_argument("--actuation-inputs", choices=("joint", "torque"), default="joint")
    ap.add_argument("--motions", default="walk_35,walk_rear_30,walk_side_25,trot_20")
    ap.add_argument("--scenario", default="ciml_sim/config/scenarios/default_gap.yaml")
    ap.add_argument("--seed", type=int, default=1001)
    args = ap.parse_args()
    robot = load_robot()
    ds = load_dataset(robot, [f"{args.bags}/{m}_{r}" for m in TRAINING for r in range(3)], progress=False)
    t0 = time.perf_counter()
    ms, torque_models = fit_models(robot, ds, args.legs, args.base_inputs, args.actuation_inputs)
    fit_s = time.perf_counter() - t0
    scenario = resolve_scenario(args.scenario, robot)
    eps = StudyEpsilon(robot, ms, torque_models, args.legs)
    effort = {}
    for motion in args.motions.split(","):
        run = run_headless(robot, scenario, motion, default_duration(motion), seed=args.seed, epsilon_fn=eps,
                           progress=False)
        effort[motion] = round(run.metrics()["rms_feedback_effort_nm"], 2)
    print(json.dumps({"legs": args.legs, "base_inputs": args.base_inputs, "actuation_inputs": args.actuation_inputs,
                      "fit_s": round(fit_s, 1), "rms_feedback_effort_nm": effort}))


if __name__ == "__main__":
    main()
