"""The joint-loop law has one definition, ciml_learning.core.conversions.commanded_torque (what the
learning side computes Γ = τ − u with, eq. 14); the plant's 1 kHz loop runs a compiled copy
(ciml_sim.joint_loop.command_coefficients + actuation). The copy must equal the specification."""
from __future__ import annotations

import numpy as np

from ciml_learning.core import conversions as cv
from ciml_sim import joint_loop

NJ = 12


def _compiled_u(ff, fb, q_t, qd_t, kp, kd, q, qd, limits, elapsed):
    """u of the compiled loop for one reading: no encoder offset or noise, no actuator effect."""
    c, c_rate, kp_j, kd_j = np.empty(NJ), np.empty(NJ), np.empty(NJ), np.empty(NJ)
    assert joint_loop.command_coefficients(ff + fb, q_t, qd_t, kp, kd, False, c, c_rate, kp_j, kd_j) == 0
    zeros, none = np.zeros(NJ), np.empty(0)
    out = joint_loop.JointReading(*(np.empty(NJ) for _ in range(5)))
    stamp = 3.25
    actuators = joint_loop.Actuators(zeros, limits, False, zeros, zeros, False, np.ones(NJ), zeros)
    command = joint_loop.HeldCommand(c, c_rate, kp_j, kd_j, bool(c_rate.any()), stamp)
    joint_loop.actuation(q, qd, actuators, command, none, none, stamp + elapsed, out)
    np.testing.assert_array_equal(out.tau, out.u)  # no actuator effect: τ = u
    return out.u


def test_compiled_joint_loop_equals_commanded_torque_on_random_inputs():
    rng = np.random.default_rng(21)
    clipped = 0
    for _ in range(500):
        ff, fb = rng.normal(0, 40, NJ), rng.normal(0, 10, NJ)
        q_t, qd_t = rng.normal(0, 1.0, NJ), rng.normal(0, 3.0, NJ)
        kp, kd = rng.uniform(0, 500, NJ), rng.uniform(0, 20, NJ)
        q, qd = q_t + rng.normal(0, 0.1, NJ), qd_t + rng.normal(0, 1.0, NJ)
        limits = rng.uniform(20, 200, NJ)
        elapsed = float(rng.choice([0.0, rng.uniform(0, 0.01)]))
        spec = cv.commanded_torque(ff, fb, q_t, qd_t, kp, kd, q, qd, limits, elapsed=elapsed)
        got = _compiled_u(ff, fb, q_t, qd_t, kp, kd, q, qd, limits, elapsed)
        # the same law; the coefficient form rounds differently (terms of up to ~1e3 Nm)
        np.testing.assert_allclose(got, spec, rtol=0, atol=1e-9)
        clipped += int((np.abs(spec) == limits).sum())
    assert clipped > 100  # the clip is exercised


def test_torque_command_total_is_commanded_torque():
    rng = np.random.default_rng(3)
    f = {k: rng.normal(0, 5, NJ) for k in ("feedforward", "feedback_linearization", "position_target",
                                           "velocity_target")}
    kp, kd = rng.uniform(0, 300, NJ), rng.uniform(0, 10, NJ)
    cmd = cv.TorqueCommandArrays(mode=0, stiffness=kp, damping=kd, **f)
    q, qd, limits = rng.normal(0, 1, NJ), rng.normal(0, 1, NJ), np.full(NJ, 150.0)
    np.testing.assert_array_equal(cmd.total(q, qd, limits, elapsed=0.002), cv.commanded_torque(
        f["feedforward"], f["feedback_linearization"], f["position_target"], f["velocity_target"], kp, kd, q, qd,
        limits, elapsed=0.002))
