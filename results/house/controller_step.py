"""Where one control step of `ciml bench --only id_controller_step` goes: the same steps as
ciml_control.benchmarks.compute_benchmark (trot_35, 2,000 steps, a fixed Φ̃', Γ prediction, a
perturbed measured state), timed in two parts: ε at the reference (the controller's Pinocchio pass
at qᵈ, `desired_terms`, the contact-invariant basis and eq. 17) and `IdController.compute` (one
compiled call: the measured state's pass, the QP in eq. 19's null space, the feedback).

    python results/house/controller_step.py
"""
from __future__ import annotations

import time

import numpy as np
import pinocchio as pin

from ciml_control.controller import IdController
from ciml_control.references import make_reference, standing_configuration
from ciml_learning.core.dynamics import selection_matrix
from ciml_learning.core.extraction import combined_error
from ciml_learning.core.projection import contact_invariant_basis
from ciml_learning.core.robot import load_robot

robot = load_robot()
ref = make_reference(robot, "trot_35", standing_configuration(robot, 0.002))
rng = np.random.default_rng(0)
points = [ref.sample(t) for t in 1.0 + np.arange(2000) / 250.0]
ctrl = IdController(robot)
S = selection_matrix(robot)
phi = rng.normal(0.0, 5.0, len(robot.rbd_error_names))
gamma = rng.normal(0.0, 2.0, robot.n_joints)


def epsilon(p):
    return combined_error(contact_invariant_basis(ctrl.desired_terms(p)[2], robot.leg_joints), phi, gamma, S)


for p in points[:50]:  # warm-up, as the benchmark
    ctrl.compute(p.q, p.v, p.contacts, p, epsilon(p))
parts: dict[str, list[float]] = {"ε at the reference": [], "compute()": [], "step": []}
for p in points:
    q = pin.integrate(robot.model, p.q, 0.005 * rng.standard_normal(robot.nv))
    v = p.v + 0.05 * rng.standard_normal(robot.nv)
    t0 = time.perf_counter()
    e = epsilon(p)
    t1 = time.perf_counter()
    ctrl.compute(q, v, p.contacts, p, e)
    t2 = time.perf_counter()
    parts["ε at the reference"].append(t1 - t0)
    parts["compute()"].append(t2 - t1)
    parts["step"].append(t2 - t0)
for name, t in parts.items():
    us = np.array(t) * 1e6
    print(f"{name}: p50 {np.percentile(us, 50):.1f} µs, p99 {np.percentile(us, 99):.1f} µs")
