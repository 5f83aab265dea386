"""Every effect type acts where the real one acts, and nowhere else.

Method (one test per effect type): the robot is put in the air (no contact) at the same
state with the same command in a plant with the effect and in a nominal plant. Then
    Δf = RNEA_nominal(q, v, v̇_effect) − RNEA_nominal(q, v, v̇_nominal)
is the generalized force the effect adds to the nominal model's equation of motion,
and Δτ, Δq, … the change of each measurement. Both must be non-zero exactly where the
effect acts, and the ground truth the plant reports for the effect must equal Δf.
"""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from ciml_learning.core.dynamics import RigidBodyDynamics
from ciml_learning.core.robot import load_robot
from ciml_sim.mjcf import mj_to_pin_force
from ciml_sim.plant import Plant, true_pinocchio_model
from ciml_sim.scenario import nominal_scenario, parse_scenario

ROBOT = load_robot()
NJ = ROBOT.n_joints
J = {n: i for i, n in enumerate(ROBOT.joint_names)}
G = 9.81


def _scenario(*effects: dict, noise: dict | None = None):
    return parse_scenario({"name": "test", "sensor_noise": noise or {}, "effects": list(effects)}, ROBOT)


def _airborne_state(seed: int = 0) -> tuple[np.ndarray, np.ndarray, tuple]:
    rng = np.random.default_rng(seed)
    q = pin.neutral(ROBOT.model)
    q[7:] = ROBOT.standing_joints
    q[2] = 2.0
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.1, -0.05, 0.3)).coeffs()
    v = rng.normal(scale=0.5, size=ROBOT.nv)
    v[6:] = rng.choice([-1.0, 1.0], NJ) * rng.uniform(0.5, 1.5, NJ)  # every joint slides
    cmd = (rng.normal(scale=10.0, size=NJ), q[7:] + 0.05, np.zeros(NJ), np.full(NJ, 100.0), np.full(NJ, 2.0))
    return q, v, cmd


def _evaluate(scenario, q, v, cmd):
    plant = Plant(ROBOT, scenario)
    plant.reset(q, v)
    plant.set_command(*cmd)
    m = plant.measure()
    g = plant.ground_truth()
    f = pin.rnea(ROBOT.model, ROBOT.model.createData(), g.q, g.v, g.vdot).copy()
    return m, g, f


def _compare(effect: dict, seed: int = 0, cmd_override: dict | None = None):
    q, v, cmd = _airborne_state(seed)
    if cmd_override:
        cmd = tuple(cmd_override.get(i, c) for i, c in enumerate(cmd))
    m0, g0, f0 = _evaluate(nominal_scenario(), q, v, cmd)
    m1, g1, f1 = _evaluate(_scenario(effect), q, v, cmd)
    assert np.all(g1.contact_forces == 0) and not m1.contacts.any()  # in the air
    return m0, m1, g0, g1, f1 - f0


def _nonzero(x: np.ndarray, tol: float = 1e-8) -> set[int]:
    return set(np.flatnonzero(np.abs(x) > tol).tolist())


def _same_measurements(m0, m1, *, q=True, tau=True, orientation=True):
    if q:
        np.testing.assert_array_equal(m1.q, m0.q)
    np.testing.assert_array_equal(m1.qd, m0.qd)
    if tau:
        np.testing.assert_array_equal(m1.tau_measured, m0.tau_measured)
    np.testing.assert_array_equal(m1.base_position, m0.base_position)
    if orientation:
        np.testing.assert_allclose(m1.base_orientation, m0.base_orientation, atol=1e-15)
    np.testing.assert_allclose(m1.base_linear_velocity, m0.base_linear_velocity, atol=1e-15)
    np.testing.assert_array_equal(m1.base_angular_velocity, m0.base_angular_velocity)


def _only_truth(g1, df, label: str, atol: float = 1e-6) -> None:
    assert list(g1.effect_forces) == [label]
    np.testing.assert_allclose(g1.effect_forces[label], df, atol=atol, rtol=1e-6)


# --- joint side: after the torque sensor (Φ̃, not Γ) ----------------------------------------------


def test_coulomb_friction_changes_only_that_joints_force_not_the_measured_torque():
    m0, m1, g0, g1, df = _compare({"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0})
    j = J["rf_kfe_joint"]
    assert _nonzero(df) == {6 + j}
    assert df[6 + j] == pytest.approx(-6.0 * np.sign(g1.v[6 + j]), abs=1e-6)  # sliding: full Coulomb force
    _same_measurements(m0, m1)
    _only_truth(g1, df, "joint_coulomb_friction_rf_kfe")


def test_coulomb_friction_holds_a_joint_still_below_its_value():
    """True stiction: a joint at rest under a torque smaller than the friction stays at rest."""
    plant = Plant(ROBOT, _scenario({"type": "joint_coulomb_friction", "joint": "all", "value": 30.0}))
    q, _, _ = _airborne_state()
    plant.reset(q, np.zeros(ROBOT.nv))
    plant.model.opt.gravity[:] = 0.0
    plant.set_command(np.full(NJ, 10.0), np.zeros(NJ), np.zeros(NJ), np.zeros(NJ), np.zeros(NJ))
    plant.step(200)
    assert np.abs(plant.data.qvel[6:]).max() < 1e-3
    g = plant.ground_truth()
    np.testing.assert_allclose(g.effect_forces["joint_coulomb_friction_all"][6:], -10.0, atol=1e-2)


def test_viscous_friction_changes_only_that_joints_force():
    m0, m1, g0, g1, df = _compare({"type": "joint_viscous_friction", "joint": "lh_hfe_joint", "value": 4.0})
    j = J["lh_hfe_joint"]
    assert _nonzero(df) == {6 + j}
    assert df[6 + j] == pytest.approx(-4.0 * g1.v[6 + j], rel=1e-9)
    _same_measurements(m0, m1)
    _only_truth(g1, df, "joint_viscous_friction_lh_hfe")


def test_stribeck_friction_follows_the_stribeck_curve_at_that_joint_only():
    e = {"type": "joint_stribeck_friction", "joint": "lf_kfe_joint", "breakaway": 12.0, "coulomb": 4.0, "velocity": 0.5}
    m0, m1, g0, g1, df = _compare(e)
    j = J["lf_kfe_joint"]
    qd = g1.v[6 + j]
    level = 4.0 + 8.0 * np.exp(-(qd / 0.5) ** 2)
    assert _nonzero(df) == {6 + j}
    assert df[6 + j] == pytest.approx(-level * np.sign(qd), abs=1e-6)
    _same_measurements(m0, m1)
    _only_truth(g1, df, "joint_stribeck_friction_lf_kfe")


def test_joint_spring_acts_at_that_joint_only():
    m0, m1, g0, g1, df = _compare({"type": "joint_spring", "joint": "rh_hfe_joint", "stiffness": 50.0, "rest": 0.2})
    j = J["rh_hfe_joint"]
    assert _nonzero(df) == {6 + j}
    assert df[6 + j] == pytest.approx(-50.0 * (g1.q[7 + j] - 0.2), rel=1e-9)
    _same_measurements(m0, m1)
    _only_truth(g1, df, "joint_spring_rh_hfe")


def test_torque_ripple_acts_at_that_joint_only():
    m0, m1, g0, g1, df = _compare({"type": "torque_ripple", "joint": "lh_kfe_joint", "amplitude": 3.0, "period": 0.3})
    j = J["lh_kfe_joint"]
    assert _nonzero(df) == {6 + j}
    assert df[6 + j] == pytest.approx(3.0 * np.sin(2 * np.pi * g1.q[7 + j] / 0.3), rel=1e-9)
    _same_measurements(m0, m1)
    _only_truth(g1, df, "torque_ripple_lh_kfe")


# --- actuator: between command and torque sensor (Γ) --------------------------------------------


def test_torque_gain_changes_the_measured_torque_of_that_joint_only():
    m0, m1, g0, g1, df = _compare({"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.85})
    j = J["lf_haa_joint"]
    dtau = m1.tau_measured - m0.tau_measured
    assert _nonzero(dtau) == {j}
    assert dtau[j] == pytest.approx(-0.15 * m0.u_commanded[j], rel=1e-9)
    np.testing.assert_array_equal(m1.u_commanded, m0.u_commanded)  # the command is the same
    assert _nonzero(df) == {6 + j}
    assert df[6 + j] == pytest.approx(dtau[j], rel=1e-6)
    _same_measurements(m0, m1, tau=False)
    _only_truth(g1, df, "torque_gain_lf_haa")


def test_torque_offset_changes_the_measured_torque_of_that_joint_only():
    m0, m1, g0, g1, df = _compare({"type": "torque_offset", "joint": "rh_kfe_joint", "value": 3.0})
    j = J["rh_kfe_joint"]
    dtau = m1.tau_measured - m0.tau_measured
    assert _nonzero(dtau) == {j} and dtau[j] == pytest.approx(3.0, rel=1e-12)
    assert _nonzero(df) == {6 + j} and df[6 + j] == pytest.approx(3.0, rel=1e-6)
    _same_measurements(m0, m1, tau=False)
    _only_truth(g1, df, "torque_offset_rh_kfe")


def test_actuator_lag_is_a_first_order_lag_between_command_and_sensor():
    tc = 0.012
    m0, m1, g0, g1, df = _compare({"type": "actuator_lag", "joints": ["lf_hfe_joint", "rh_haa_joint"],
                                   "time_constant": tc})
    lagged = {J["lf_hfe_joint"], J["rh_haa_joint"]}
    dtau = m1.tau_measured - m0.tau_measured
    assert _nonzero(dtau) == lagged
    assert _nonzero(df) == {6 + j for j in lagged}
    np.testing.assert_allclose(df[6:], dtau, rtol=1e-6, atol=1e-6)
    _same_measurements(m0, m1, tau=False)
    _only_truth(g1, df, "actuator_lag_lf_hfe_rh_haa")
    # the step response: τ_k = τ_{k−1} + Δt/(T+Δt) (u − τ_{k−1}) → 63 % after T (1 % discretisation)
    plant = Plant(ROBOT, _scenario({"type": "actuator_lag", "joints": "all", "time_constant": tc}))
    q, _, _ = _airborne_state()
    plant.reset(q, np.zeros(ROBOT.nv))
    plant.set_command(np.full(NJ, 20.0), np.zeros(NJ), np.zeros(NJ), np.zeros(NJ), np.zeros(NJ))
    taus = []
    for _ in range(40):
        taus.append(plant.measure().tau_measured[0])
        plant.step(1)
    k = int(round(tc / 1e-3))
    assert taus[k - 1] / 20.0 == pytest.approx(1 - np.exp(-1), abs=0.015)
    assert 0 < taus[0] < taus[1] < taus[-1] < 20.0


# --- rigid bodies ---------------------------------------------------------------------------------


def test_payload_acts_on_the_base_only():
    m0, m1, g0, g1, df = _compare({"type": "payload", "mass": 6.0, "com": [0.15, 0.0, 0.05]})
    assert _nonzero(df, 1e-6) <= set(range(6)) and _nonzero(df, 1e-6)
    _same_measurements(m0, m1)
    _only_truth(g1, df, "payload")


def test_payload_changes_the_base_wrench_needed_to_stand_by_mg_at_its_com():
    """Statics: the generalized gravity force on the base grows by m·g applied at the payload's CoM."""
    mass, com = 6.0, np.array([0.15, 0.0, 0.05])
    scen = _scenario({"type": "payload", "mass": mass, "com": com.tolist()})
    plant = Plant(ROBOT, scen)
    q = plant.standing_configuration()
    q[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.05, -0.1, 0.4)).coeffs()
    nv = ROBOT.nv
    g_nom = RigidBodyDynamics(ROBOT).nonlinear_effects(q, np.zeros(nv))
    g_true = pin.rnea(plant.true_model, plant.true_model.createData(), q, np.zeros(nv), np.zeros(nv))
    R = pin.Quaternion(q[3:7]).matrix()
    trunk = ROBOT.model.frames[ROBOT.model.getFrameId("trunk")].placement
    c = trunk.act(com)  # payload CoM in the base frame
    f = R.T @ np.array([0.0, 0.0, mass * G])  # weight in the base frame (opposing gravity)
    expected = np.r_[f, np.cross(c, f), np.zeros(NJ)]
    np.testing.assert_allclose(g_true - g_nom, expected, atol=1e-9)
    # the MuJoCo model carries it too: bias forces differ by the same wrench
    d = plant.data
    plant.reset(q)
    mujoco.mj_forward(plant.model, d)
    nominal = Plant(ROBOT, nominal_scenario())
    nominal.reset(q)
    mujoco.mj_forward(nominal.model, nominal.data)
    dh = mj_to_pin_force(q, d.qfrc_bias - nominal.data.qfrc_bias)
    np.testing.assert_allclose(dh, expected, atol=1e-8)
    assert plant.model.body_mass.sum() == pytest.approx(ROBOT.total_mass + mass)


@pytest.mark.parametrize("scale", [1.4, 0.6])
def test_link_mass_scale_acts_on_the_base_and_that_legs_joints_only(scale):
    m0, m1, g0, g1, df = _compare({"type": "link_mass_scale", "link": "lf_lowerleg", "value": scale})
    lf = {6 + j for j in ROBOT.leg_joints[ROBOT.foot_frames.index("lf_foot")]}
    touched = _nonzero(df, 1e-6)
    assert touched <= set(range(6)) | lf and lf & touched
    _same_measurements(m0, m1)
    _only_truth(g1, df, "link_mass_scale_lf_lowerleg")
    # the link's mass changed by (scale − 1)·m_link, everything else equal
    plant = Plant(ROBOT, _scenario({"type": "link_mass_scale", "link": "lf_lowerleg", "value": scale}))
    _, inertia = ROBOT.link_inertias["lf_lowerleg"]
    assert plant.model.body_mass.sum() - ROBOT.total_mass == pytest.approx((scale - 1) * inertia.mass, rel=1e-9)
    body = plant.model.body("lf_kfe").id
    nominal = Plant(ROBOT, nominal_scenario())
    changed = np.flatnonzero(~np.isclose(plant.model.body_mass, nominal.model.body_mass))
    assert changed.tolist() == [body]


# --- measurement only -------------------------------------------------------------------------------


# --- the torque sensor: the reading changes, the torque the joint receives does not --------------


@pytest.mark.parametrize("effect, expected", [
    ({"type": "torque_sensor_gain", "joint": "lf_kfe_joint", "value": 0.8}, lambda tau, q: -0.2 * tau),
    ({"type": "torque_sensor_offset", "joint": "lf_kfe_joint", "value": -4.0}, lambda tau, q: -4.0),
    ({"type": "torque_sensor_ripple", "joint": "lf_kfe_joint", "amplitude": 6.0, "period": 2 * np.pi / 10},
     lambda tau, q: 6.0 * np.sin(10.0 * q)),
])
def test_torque_sensor_effects_change_only_the_measured_torque(effect, expected):
    """Unlike torque_gain/torque_offset (the actuator), a sensor effect exerts no force (no ground-truth
    entry, the same motion) and changes the reading by exactly its law at that joint."""
    m0, m1, g0, g1, df = _compare(effect)
    j = J["lf_kfe_joint"]
    dtau = m1.tau_measured - m0.tau_measured
    assert _nonzero(dtau) == {j}
    assert dtau[j] == pytest.approx(expected(g1.tau[j], g1.q[7 + j]), rel=1e-9)
    np.testing.assert_array_equal(g1.tau, g0.tau)  # the actuator's torque is the same
    np.testing.assert_array_equal(m1.u_commanded, m0.u_commanded)
    assert _nonzero(df) == set() and g1.effect_forces == {}
    _same_measurements(m0, m1, tau=False)


def test_torque_sensor_effects_in_the_compiled_closed_loop_match_the_step_by_step_sample():
    """The compiled closed loop's sensor (joint_loop.closed_loop → sense) reads like Plant.measure."""
    effects = [{"type": "torque_sensor_gain", "joint": "rh_hfe_joint", "value": 1.2},
               {"type": "torque_sensor_offset", "joint": "lf_haa_joint", "value": 2.5}]
    plant = Plant(ROBOT, _scenario(*effects))
    q, v, cmd = _airborne_state(2)
    plant.reset(q, v)
    plant.set_command(*cmd)
    m = plant.measure()
    g = plant.ground_truth()
    expected = g.tau.copy()
    expected[J["rh_hfe_joint"]] *= 1.2
    expected[J["lf_haa_joint"]] += 2.5
    np.testing.assert_allclose(m.tau_measured, expected, rtol=1e-12, atol=1e-12)
    assert plant.compiled_state().sensors.sensor.shape == (NJ, 4)


def test_encoder_offset_changes_only_the_measured_position():
    kp0 = {3: np.zeros(NJ)}  # no position feedback: the offset cannot move anything
    m0, m1, g0, g1, df = _compare({"type": "encoder_offset", "joint": "rf_hfe_joint", "value": 0.02}, cmd_override=kp0)
    j = J["rf_hfe_joint"]
    dq = m1.q - m0.q
    assert _nonzero(dq) == {j} and dq[j] == pytest.approx(0.02, rel=1e-9)
    assert _nonzero(df) == set()
    assert g1.effect_forces == {}
    _same_measurements(m0, m1, q=False)
    # with position feedback the joint loop sees the offset encoder, like the robot's:
    # u changes by −K_p·offset at that joint, and τ − u (Γ) does not change
    m0, m1, *_ = _compare({"type": "encoder_offset", "joint": "rf_hfe_joint", "value": 0.02})
    du = m1.u_commanded - m0.u_commanded
    assert _nonzero(du) == {j} and du[j] == pytest.approx(-100.0 * 0.02, rel=1e-6)
    np.testing.assert_allclose(m1.tau_measured - m1.u_commanded, m0.tau_measured - m0.u_commanded, atol=1e-12)


def test_imu_tilt_changes_only_the_orientation_measurement():
    m0, m1, g0, g1, df = _compare({"type": "base_imu_tilt", "roll": 0.01, "pitch": -0.005})
    assert _nonzero(df) == set() and g1.effect_forces == {}
    _same_measurements(m0, m1, orientation=False)
    R0 = pin.Quaternion(m0.base_orientation).matrix()
    R1 = pin.Quaternion(m1.base_orientation).matrix()
    np.testing.assert_allclose(R0.T @ R1, pin.rpy.rpyToMatrix(0.01, -0.005, 0.0), atol=1e-12)
    np.testing.assert_allclose(R0, pin.Quaternion(g1.q[3:7]).matrix(), atol=1e-12)  # truth unbiased


# --- sensor noise -------------------------------------------------------------------------------------


def test_sensor_noise_has_the_given_standard_deviations_and_is_reproducible():
    noise = {"q": 0.001, "qd": 0.02, "tau": 0.5, "base_orientation": 0.002, "base_position": 0.003,
             "base_velocity": 0.01}

    def samples(seed):
        plant = Plant(ROBOT, _scenario(noise=noise), seed=seed)
        q, v, cmd = _airborne_state()
        plant.model.opt.gravity[:] = 0.0
        plant.reset(q, np.zeros(ROBOT.nv))
        plant.set_command(np.zeros(NJ), np.zeros(NJ), np.zeros(NJ), np.zeros(NJ), np.zeros(NJ))
        rows = []
        for _ in range(400):
            m = plant.measure()
            g = plant.ground_truth()
            R_err = pin.Quaternion(g.q[3:7]).matrix().T @ pin.Quaternion(m.base_orientation).matrix()
            rows.append(np.r_[m.q - g.q[7:], m.qd - g.v[6:], m.tau_measured - g.tau, pin.log3(R_err),
                              m.base_position - g.q[:3], m.base_linear_velocity - g.v[:3]])
            plant.step(1)
        return np.array(rows)

    a = samples(1)
    sizes = [NJ, NJ, NJ, 3, 3, 3]
    cuts = np.cumsum([0] + sizes)
    for (key, n), lo, hi in zip([("q", NJ), ("qd", NJ), ("tau", NJ), ("base_orientation", 3), ("base_position", 3),
                                 ("base_velocity", 3)], cuts[:-1], cuts[1:]):
        std = a[:, lo:hi].std()
        assert std == pytest.approx(noise[key], rel=0.1), key
        assert abs(a[:, lo:hi].mean()) < 4 * noise[key] / np.sqrt(a[:, lo:hi].size)
    np.testing.assert_array_equal(samples(1), a)
    assert not np.array_equal(samples(2), a)


# --- all effects together ------------------------------------------------------------------------------


ALL_EFFECTS = [
    {"type": "payload", "mass": 6.0, "com": [0.15, 0.0, 0.05]},
    {"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0},
    {"type": "joint_coulomb_friction", "joint": "all", "value": 1.0},
    {"type": "joint_viscous_friction", "joint": "lh_hfe_joint", "value": 4.0},
    {"type": "actuator_lag", "joints": "all", "time_constant": 0.012},
    {"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.85},
    {"type": "torque_gain", "joint": "lf_haa_joint", "value": 1.05},
    {"type": "torque_offset", "joint": "rh_kfe_joint", "value": 3.0},
    {"type": "link_mass_scale", "link": "lf_lowerleg", "value": 1.4},
    {"type": "encoder_offset", "joint": "rf_hfe_joint", "value": 0.02},
    {"type": "base_imu_tilt", "roll": 0.01, "pitch": -0.005},
    {"type": "joint_stribeck_friction", "joint": "lh_kfe_joint", "breakaway": 6.0, "coulomb": 2.0, "velocity": 0.1},
    {"type": "joint_spring", "joint": "rh_hfe_joint", "stiffness": 30.0, "rest": 0.5},
    {"type": "torque_ripple", "joint": "lf_kfe_joint", "amplitude": 2.0, "period": 0.5},
]


def test_ground_truth_closes_the_nominal_equation_of_motion_with_contacts():
    """M v̇ + h (nominal) = Sᵀu + contact forces + Σ effect forces, at every sample of a
    standing sway with every effect at once (effects combine; nothing is missing)."""
    from ciml_control.standing import StandingController

    scen = _scenario(*ALL_EFFECTS)
    plant = Plant(ROBOT, scen)
    ctl = StandingController(ROBOT)
    q0 = plant.standing_configuration()
    dyn = RigidBodyDynamics(ROBOT)
    data = ROBOT.model.createData()
    worst, worst_feet, checked = 0.0, 0.0, 0
    for k in range(300):
        t = k * 0.004
        q_des = q0.copy()
        q_des[7:] += 0.08 * np.sin(2 * np.pi * 1.5 * t + np.arange(NJ))  # legs move: friction and lag act
        plant.measure()
        g = plant.ground_truth()
        if k > 50:
            lhs = pin.rnea(ROBOT.model, data, g.q, g.v, g.vdot)
            d = plant.data
            rows = np.isin(d.efc_type[: d.nefc], [mujoco.mjtConstraint.mjCNSTR_CONTACT_ELLIPTIC])
            f_contact = np.zeros(ROBOT.nv)
            mujoco.mj_mulJacTVec(plant.model, d, f_contact, np.where(rows, d.efc_force[: d.nefc], 0.0))
            rhs = np.r_[np.zeros(6), g.u] + mj_to_pin_force(g.q, f_contact) + sum(g.effect_forces.values())
            worst = max(worst, np.abs(lhs - rhs).max() / np.abs(lhs).max())
            # the same with the nominal model's point feet: the 2 mm foot radius is the only difference
            Jf = dyn.foot_jacobians(g.q)
            rhs_feet = rhs - mj_to_pin_force(g.q, f_contact) + np.einsum("fiv,fi->v", Jf, g.contact_forces)
            worst_feet = max(worst_feet, np.abs(lhs - rhs_feet).max())
            checked += 1
        c = ctl.compute(q_des, np.ones(ROBOT.n_feet, bool))
        plant.set_command(c.feedforward, c.q_target, c.qd_target, c.kp, c.kd)
        plant.step(4)
    assert checked > 200 and g.q[2] > 0.5
    assert g.contact_forces[:, 2].sum() > 0.9 * (ROBOT.total_mass + 6.0) * G * 0.5
    assert worst < 1e-6
    assert worst_feet < 0.5  # [Nm]: moments of the tangential forces about the 2 mm foot sphere centre
    expected_labels = {"payload", "joint_coulomb_friction_rf_kfe", "joint_coulomb_friction_all",
                       "joint_viscous_friction_lh_hfe", "actuator_lag_all", "torque_gain_lf_haa",
                       "torque_gain_lf_haa_2", "torque_offset_rh_kfe", "link_mass_scale_lf_lowerleg",
                       "joint_stribeck_friction_lh_kfe", "joint_spring_rh_hfe", "torque_ripple_lf_kfe"}
    assert set(g.effect_forces) == expected_labels


def test_actuator_effects_add_up_to_the_actuation_error():
    """Σ actuator-effect forces = τ − u (Γ of eq. 14, noise-free), joint by joint."""
    scen = _scenario(*ALL_EFFECTS)
    plant = Plant(ROBOT, scen)
    q, v, cmd = _airborne_state()
    plant.reset(q, v)
    plant.set_command(*cmd)
    plant.step(7)
    m = plant.measure()
    g = plant.ground_truth()
    act = sum(f for k, f in g.effect_forces.items() if k.startswith(("actuator_lag", "torque_gain", "torque_offset")))
    np.testing.assert_allclose(act[6:], g.tau - g.u, atol=1e-9)
    np.testing.assert_allclose(m.tau_measured, g.tau)
    assert np.all(act[:6] == 0)


def test_true_model_with_no_inertial_effect_is_the_nominal_model():
    model = true_pinocchio_model(ROBOT, _scenario({"type": "torque_gain", "joint": "all", "value": 0.9}))
    for a, b in zip(model.inertias, ROBOT.model.inertias):
        assert a.isApprox(b)


BETWEEN_STEPS = ("joint_stribeck_friction", "joint_spring", "torque_ripple")


@pytest.mark.parametrize("effects", [ALL_EFFECTS, [e for e in ALL_EFFECTS if e["type"] not in BETWEEN_STEPS]],
                         ids=["python_steps", "compiled_loop"])
def test_measurement_and_physics_step_use_the_same_joint_loop(effects):
    """u and τ that measure() reports are exactly those the next physics step applies
    (same command), with noise, encoder offset, lag, gain and offset all active: on the
    step-by-step path (effects evaluated between steps) and in the compiled loop."""
    scen = _scenario(*effects, noise={"q": 0.001, "qd": 0.02, "tau": 0.3})
    plant = Plant(ROBOT, scen, seed=4)
    q, v, cmd = _airborne_state()
    plant.reset(q, v)
    plant.set_command(*cmd)
    for _ in range(1500):  # crosses a noise block (1000 steps)
        m = plant.measure()
        g = plant.ground_truth()
        plant.step(1)
        np.testing.assert_array_equal(plant.u, m.u_commanded)
        np.testing.assert_array_equal(plant.tau, g.tau)
        np.testing.assert_array_equal(plant.data.ctrl, g.tau)


def test_compiled_joint_loop_follows_the_documented_law():
    """Plant.step (compiled joint loop + mj_step by address) against the law of
    ciml_sim.plant's docstring written out here step by step in Python, on a copy of
    the same MuJoCo model: u = clip(u_ff + K_p (q_t + q̇_t (s − t_c) − q_meas) +
    K_d (q̇_t − q̇_meas)), first-order lag, gain, offset; encoder offset in q_meas."""
    effects = [{"type": "actuator_lag", "joints": "all", "time_constant": 0.012},
               {"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.85},
               {"type": "torque_offset", "joint": "rh_kfe_joint", "value": 3.0},
               {"type": "encoder_offset", "joint": "rf_hfe_joint", "value": 0.02},
               {"type": "joint_coulomb_friction", "joint": "all", "value": 1.0}]
    plant = Plant(ROBOT, _scenario(*effects))
    q, v, (u_ff, q_t, _, kp, kd) = _airborne_state(3)
    qd_t = np.linspace(-0.5, 0.5, NJ)
    plant.reset(q, v)
    m, d = plant.model, mujoco.MjData(plant.model)
    d.qpos[:], d.qvel[:], d.time = plant.data.qpos, plant.data.qvel, plant.data.time
    stamp = -0.003
    plant.set_command(u_ff, q_t, qd_t, kp, kd, stamp=stamp)
    alpha = 0.001 / (0.012 + 0.001)
    gain, offset, enc = np.ones(NJ), np.zeros(NJ), np.zeros(NJ)
    gain[J["lf_haa_joint"]], offset[J["rh_kfe_joint"]], enc[J["rf_hfe_joint"]] = 0.85, 3.0, 0.02
    lag = np.zeros(NJ)
    for n in (1, 4, 3, 4, 7):
        plant.step(n)
        for _ in range(n):
            q_meas, qd_meas = d.qpos[7:] + enc, d.qvel[6:]
            u = np.clip(u_ff + kp * (q_t + qd_t * (d.time - stamp) - q_meas) + kd * (qd_t - qd_meas),
                        -ROBOT.torque_limits, ROBOT.torque_limits)
            lag = lag + alpha * (u - lag)
            d.ctrl[:] = gain * lag + offset
            mujoco.mj_step(m, d)
        np.testing.assert_allclose(plant.u, u, rtol=0, atol=1e-9)
        np.testing.assert_allclose(plant.data.ctrl, d.ctrl, rtol=0, atol=1e-9)
        np.testing.assert_allclose(plant.data.qpos, d.qpos, rtol=0, atol=1e-9)
        assert plant.data.time == pytest.approx(d.time, rel=0, abs=1e-12)  # the plant counts steps; d adds dt
    assert np.abs(plant.data.qpos - q[[0, 1, 2, 6, 3, 4, 5] + list(range(7, ROBOT.nq))]).max() > 1e-3  # it moved
