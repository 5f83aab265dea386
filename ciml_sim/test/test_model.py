"""The MuJoCo model against the Pinocchio model (mujoco_menagerie-style model test)."""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from ciml_learning.core.robot import load_robot
from ciml_sim.mjcf import (
    build_mjcf,
    mj_mass_matrix_and_bias_in_pin,
    mj_to_pin_acceleration,
    mj_to_pin_force,
    mj_to_pin_state,
    pin_to_mj_acceleration,
    pin_to_mj_state,
)
from ciml_sim.plant import Plant
from ciml_sim.scenario import nominal_scenario

ROBOT = load_robot()


def _model():
    return mujoco.MjModel.from_xml_string(build_mjcf(ROBOT))


def _random_state(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = ROBOT.position_limits
    q = np.concatenate([rng.normal(size=3), pin.Quaternion(pin.exp3(rng.normal(size=3))).coeffs(),
                        rng.uniform(lo, hi)])
    v = rng.normal(scale=2.0, size=ROBOT.nv)
    return q, v


def test_model_compiles_without_warning_and_steps_deterministically():
    def run() -> tuple[np.ndarray, mujoco.MjData]:
        plant = Plant(ROBOT, nominal_scenario())
        q0 = plant.standing_configuration()
        nj = ROBOT.n_joints
        # hold the standing pose with the joint loop: contacts, joint loop and integrator all active
        plant.set_command(np.zeros(nj), q0[7:], np.zeros(nj), np.full(nj, 300.0), np.full(nj, 8.0))
        trace = []
        for _ in range(500):  # 2 s
            plant.measure()
            plant.step(4)
            trace.append(np.concatenate([plant.data.qpos, plant.data.qvel]))
        return np.array(trace), plant.data

    a, data = run()
    b, _ = run()
    assert np.array_equal(a, b)
    assert all(w.number == 0 for w in data.warning), [(i, w.number) for i, w in enumerate(data.warning)]
    assert np.all(np.isfinite(a))
    assert data.time == pytest.approx(2.0)
    assert a[-1, 2] > 0.5  # still standing


def test_model_has_the_urdf_inertias_and_joint_order():
    model = _model()
    assert tuple(model.joint(i).name for i in range(1, model.njnt)) == ROBOT.joint_names
    assert tuple(model.actuator(i).name for i in range(model.nu)) == ROBOT.joint_names
    assert model.body_mass.sum() == pytest.approx(ROBOT.total_mass, rel=1e-9)
    lo, hi = ROBOT.position_limits
    np.testing.assert_allclose(model.jnt_range[1:], np.stack([lo, hi], axis=1))
    assert np.all(model.dof_damping == 0) and np.all(model.dof_frictionloss == 0) and np.all(model.dof_armature == 0)


def test_mass_matrix_and_bias_forces_equal_pinocchio():
    """Empty scenario: M(q) and h(q, v) from MuJoCo equal Pinocchio's CRBA and NLE (1e-6 relative)."""
    model = _model()
    data = mujoco.MjData(model)
    pdata = ROBOT.model.createData()
    rng = np.random.default_rng(0)
    for _ in range(20):
        q, v = _random_state(rng)
        data.qpos[:], data.qvel[:] = pin_to_mj_state(q, v)
        mujoco.mj_forward(model, data)
        M_mj, h_mj = mj_mass_matrix_and_bias_in_pin(model, data, q, v)
        M = pin.crba(ROBOT.model, pdata, q)
        M = np.triu(M) + np.triu(M, 1).T
        h = pin.nonLinearEffects(ROBOT.model, pdata, q, v)
        assert np.linalg.norm(M_mj - M) <= 1e-6 * np.linalg.norm(M)
        assert np.linalg.norm(h_mj - h) <= 1e-6 * np.linalg.norm(h)


def test_pinocchio_inverse_dynamics_matches_mj_inverse():
    """M q̈ + h from Pinocchio (RNEA) equals MuJoCo's inverse dynamics, no constraint active."""
    model = _model()
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT  # no contact, no joint limit
    data = mujoco.MjData(model)
    pdata = ROBOT.model.createData()
    rng = np.random.default_rng(1)
    for _ in range(20):
        q, v = _random_state(rng)
        a = rng.normal(scale=5.0, size=ROBOT.nv)
        data.qpos[:], data.qvel[:] = pin_to_mj_state(q, v)
        data.qacc[:] = pin_to_mj_acceleration(q, v, a)
        mujoco.mj_inverse(model, data)
        tau_mj = mj_to_pin_force(q, data.qfrc_inverse)
        M = pin.crba(ROBOT.model, pdata, q)
        M = np.triu(M) + np.triu(M, 1).T
        expected = M @ a + pin.nonLinearEffects(ROBOT.model, pdata, q, v)
        np.testing.assert_allclose(pin.rnea(ROBOT.model, pdata, q, v, a), expected, rtol=1e-9, atol=1e-9)
        assert np.linalg.norm(tau_mj - expected) <= 1e-6 * np.linalg.norm(expected)


def test_state_and_acceleration_conventions_round_trip():
    rng = np.random.default_rng(2)
    model = _model()
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONSTRAINT
    data = mujoco.MjData(model)
    for _ in range(5):
        q, v = _random_state(rng)
        qpos, qvel = pin_to_mj_state(q, v)
        q2, v2 = mj_to_pin_state(qpos, qvel)
        np.testing.assert_allclose(q2, q / np.r_[1, 1, 1, [np.linalg.norm(q[3:7])] * 4, np.ones(12)], atol=1e-12)
        np.testing.assert_allclose(v2, v, atol=1e-12)
        a = rng.normal(size=ROBOT.nv)
        np.testing.assert_allclose(mj_to_pin_acceleration(q, v, pin_to_mj_acceleration(q, v, a)), a, atol=1e-12)
        # forward dynamics: MuJoCo's qacc mapped to Pinocchio equals ABA with zero torque
        data.qpos[:], data.qvel[:] = qpos, qvel
        data.ctrl[:] = 0.0
        mujoco.mj_forward(model, data)
        aba = pin.aba(ROBOT.model, ROBOT.model.createData(), q, v, np.zeros(ROBOT.nv))
        np.testing.assert_allclose(mj_to_pin_acceleration(q, v, data.qacc), aba, rtol=1e-6, atol=1e-6)


def test_the_plant_clock_counts_steps_and_does_not_drift():
    """Simulation time is origin + steps · dt, not MuJoCo's time += dt: that sum drifts (−1 ns after
    350 s, −21 ns after 1,200 s), and a sample stamped off its instant fell on the other side of a
    trot's contact switch (references.SWITCH_TOLERANCE). Also across set_time (the bridge's reset)
    and rewind_clock."""
    plant = Plant(ROBOT, nominal_scenario())
    nj = ROBOT.n_joints
    q0 = plant.standing_configuration()
    plant.set_command(np.zeros(nj), q0[7:], np.zeros(nj), np.full(nj, 300.0), np.full(nj, 8.0))
    dt = float(plant.model.opt.timestep)
    plant.set_time(1200.0)
    summed = 1200.0
    for _ in range(250):
        plant.step(4)
        summed += 4 * dt
    assert plant.time == 1200.0 + 1000 * dt
    assert summed != plant.time  # what adding dt gives instead: the test can fail
    plant.rewind_clock()
    plant.step(3)
    assert plant.time == 3 * dt
