"""The headless run's shortcuts give what the plain computation gives: the physics step
after measure() (mj_step2), the cached reference grid, the metrics from arrays."""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin

from ciml_control.references import make_reference
from ciml_control.standing import StandingController
from ciml_learning.core.robot import load_robot
from ciml_sim import recorder
from ciml_sim.mjcf import quat_xyzw_to_matrix
from ciml_sim.plant import Plant
from ciml_sim.scenario import parse_scenario, resolve_scenario

ROBOT = load_robot()


def _drive(plant: Plant, ticks: int, full_steps: bool, perturb_at: int | None = None) -> np.ndarray:
    ctl = StandingController(ROBOT)
    q0 = plant.standing_configuration()
    rows = []
    for k in range(ticks):
        m = plant.measure()
        rows.append(np.r_[m.q, m.qd, m.tau_measured, m.base_orientation, plant.data.qacc])
        c = ctl.compute(q0, m.contacts)
        plant.set_command(c.feedforward + 15 * np.sin(0.05 * k + np.arange(ROBOT.n_joints)), c.q_target,
                          c.qd_target, c.kp, c.kd)
        if k == perturb_at:
            plant.data.qvel[6:] += 0.1  # the state changes between measure() and step()
        if full_steps:
            plant._forward_state = None  # no reuse: every step a full mj_step
        plant.step(4)
    return np.array(rows)


def test_step_after_measure_is_bit_identical_to_full_steps():
    scen = parse_scenario({"name": "x", "sensor_noise": {"q": 0.001, "qd": 0.02, "tau": 0.3},
                           "effects": [{"type": "actuator_lag", "joints": "all", "time_constant": 0.01},
                                       {"type": "joint_coulomb_friction", "joint": "all", "value": 2.0},
                                       {"type": "joint_stribeck_friction", "joint": "lh_kfe_joint", "breakaway": 6.0,
                                        "coulomb": 2.0, "velocity": 0.1},
                                       {"type": "joint_spring", "joint": "rh_hfe_joint", "stiffness": 30.0,
                                        "rest": 0.5}]}, ROBOT)
    a = _drive(Plant(ROBOT, scen, seed=1), 300, full_steps=False)
    b = _drive(Plant(ROBOT, scen, seed=1), 300, full_steps=True)
    assert np.array_equal(a, b)
    # a state changed after measure() is noticed: stepped in full, as without the shortcut
    c = _drive(Plant(ROBOT, scen, seed=1), 60, full_steps=False, perturb_at=30)
    d = _drive(Plant(ROBOT, scen, seed=1), 60, full_steps=True, perturb_at=30)
    assert np.array_equal(c, d) and not np.array_equal(c, a[:60])


def test_step2_is_the_second_half_of_mj_step():
    """The MuJoCo fact the shortcut relies on: mj_forward then mj_step2 = mj_step."""
    p, r = Plant(ROBOT, resolve_scenario("nominal", ROBOT)), Plant(ROBOT, resolve_scenario("nominal", ROBOT))
    for plant, split in ((p, True), (r, False)):
        for k in range(200):
            mujoco.mj_forward(plant.model, plant.data)
            plant.data.ctrl[:] = 20 * np.sin(0.1 * k + np.arange(ROBOT.n_joints))
            (mujoco.mj_step2 if split else mujoco.mj_step)(plant.model, plant.data)
    assert np.array_equal(p.data.qpos, r.data.qpos) and np.array_equal(p.data.qvel, r.data.qvel)


def test_reference_grid_is_the_reference_sampled_in_order_and_is_not_shared_mutably():
    plant = Plant(ROBOT, resolve_scenario("nominal", ROBOT))
    q_stand = plant.standing_configuration()
    ref = make_reference(ROBOT, "trot_35", q_stand)
    grid = recorder.reference_grid(ROBOT, "trot_35", q_stand, make_reference(ROBOT, "trot_35", q_stand))
    assert recorder.reference_grid(ROBOT, "trot_35", q_stand, ref) is grid  # cached
    expected = [ref.sample(k / recorder.CONTROL_RATE) for k in range(120)]
    for k, p in enumerate(expected):
        g = grid.point(k)
        assert g.t == p.t
        for name in ("q", "v", "a", "contacts"):
            assert np.array_equal(getattr(g, name), getattr(p, name)), (k, name)
    g = grid.point(5)
    g.q[:] = 0.0  # a caller's change stays with the caller
    assert np.array_equal(grid.point(5).q, expected[5].q)


def test_metrics_from_arrays_match_the_per_sample_formulas():
    rng = np.random.default_rng(0)
    n = 50
    qpos = np.zeros((n, 19))
    q_ref = np.zeros((n, 19))
    for k in range(n):
        R = pin.rpy.rpyToMatrix(*(0.3 * rng.standard_normal(3)))
        R_ref = pin.rpy.rpyToMatrix(*(0.3 * rng.standard_normal(3)))
        x, y, z, w = pin.Quaternion(R).coeffs()
        qpos[k, :7] = np.r_[rng.standard_normal(3), 1.3 * np.array([w, x, y, z])]  # not normalised
        q_ref[k, :7] = np.r_[rng.standard_normal(3), pin.Quaternion(R_ref).coeffs()]
        qpos[k, 7:] = rng.standard_normal(12)
        q_ref[k, 7:] = rng.standard_normal(12)
    result = recorder.RunResult()
    recorder._metrics_from_arrays(result, np.arange(n) * 0.004, np.ones(n), qpos, q_ref)
    for k in range(n):
        quat = qpos[k, [4, 5, 6, 3]] / np.linalg.norm(qpos[k, 3:7])
        R, R_ref = quat_xyzw_to_matrix(quat), quat_xyzw_to_matrix(q_ref[k, 3:7])
        assert abs(result.attitude_error[k] - np.linalg.norm(pin.log3(R_ref.T @ R))) < 1e-12
        assert abs(result.base_position_error[k] - np.linalg.norm(qpos[k, :3] - q_ref[k, :3])) < 1e-15
        assert abs(result.joint_error[k] - np.sqrt(np.mean((qpos[k, 7:] - q_ref[k, 7:]) ** 2))) < 1e-15
    m = result.metrics()
    assert m["samples"] == n and m["rms_feedback_effort_nm"] == 1.0
