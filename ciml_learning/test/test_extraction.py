"""Eq. (11), (14), (17) against synthetic ground truth built from eq. (3)."""
from __future__ import annotations

import itertools

import numpy as np
import pinocchio as pin
import pytest

from ciml_learning.core.dynamics import RigidBodyDynamics, selection_matrix
from ciml_learning.core.extraction import (
    actuation_error,
    combined_error,
    extract,
    learning_input_names,
    learning_inputs,
    observation_operators,
    observe,
)
from ciml_learning.core.projection import (
    DEFAULT_GAMMA,
    contact_invariant_bases,
    contact_invariant_basis,
    contact_jacobian,
    leg_coupling,
    projector,
)
from ciml_learning.core.robot import load_robot

ROBOT = load_robot()
CONFIGS = [np.array(c, dtype=bool) for c in itertools.product([False, True], repeat=4)]


def random_state(rng, spread=0.35):
    """Random configuration in HyQ's working region (around a crouched stance, within
    limits), where every leg block is well conditioned (σ_min > γ): there eq. (11) is exact."""
    lo, hi = ROBOT.position_limits
    for _ in range(100):
        stance = np.array([0.0, 0.7, -1.4, 0.0, -0.7, 1.4] * 2)  # lf, lh, rf, rh
        qj = np.clip(stance + rng.uniform(-spread, spread, 12), lo + 0.05, hi - 0.05)
        quat = pin.Quaternion(pin.rpy.rpyToMatrix(*rng.uniform(-0.3, 0.3, 3))).coeffs()
        q = np.concatenate([rng.uniform(-1, 1, 3), quat, qj])
        J = RigidBodyDynamics(ROBOT).foot_jacobians(q)
        if all(np.linalg.svd(J[i][:, 6 + np.array(leg)], compute_uv=False)[-1] > 2 * DEFAULT_GAMMA
               for i, leg in enumerate(ROBOT.leg_joints)):
            return q, rng.normal(size=ROBOT.nv)
    raise AssertionError("no well-conditioned state found")


def synthesize(rng, contacts, q, v, phi_prime):
    """τ and q̈ consistent with eq. (3): M q̈ + h + J'ᵀΦ̃' = Sᵀτ + J_cᵀλ, random λ."""
    dyn = RigidBodyDynamics(ROBOT)
    terms = dyn.terms(q, v)
    basis = contact_invariant_basis(terms.foot_jacobians, ROBOT.leg_joints)
    Jc = contact_jacobian(terms.foot_jacobians, contacts)
    lam = rng.normal(scale=100.0, size=Jc.shape[0])
    a = rng.normal(size=ROBOT.nv)
    rhs_extra = basis.T @ phi_prime - Jc.T @ lam
    M, h = terms.mass_matrix, terms.nonlinear_effects
    # base rows have no actuation: solve them for the base acceleration
    a[:6] = np.linalg.solve(M[:6, :6], -(M[:6, 6:] @ a[6:] + h[:6] + rhs_extra[:6]))
    tau = (M @ a + h + rhs_extra)[6:]
    return a, tau


@pytest.mark.parametrize("config", CONFIGS, ids=lambda c: "".join("C" if x else "s" for x in c))
def test_unconstrained_entries_recovered_for_every_contact_configuration(config):
    rng = np.random.default_rng(int(config @ [1, 2, 4, 8]))
    for _ in range(5):
        q, v = random_state(rng)
        phi = rng.normal(scale=20.0, size=ROBOT.nv)
        a, tau = synthesize(rng, config, q, v, phi)
        res = extract(ROBOT, q[None], v[None], a[None], tau[None], tau[None], config[None])
        expected_mask = np.concatenate([np.ones(6, bool), np.repeat(~config, 3)])
        assert np.array_equal(res.rbd_observed[0], expected_mask)
        np.testing.assert_allclose(res.rbd_error[0][expected_mask], phi[expected_mask], atol=1e-8, rtol=0)
        assert np.all(res.rbd_error[0][~expected_mask] == 0.0)


def test_same_error_agrees_across_contact_configurations():
    rng = np.random.default_rng(7)
    q, v = random_state(rng)
    phi = rng.normal(scale=20.0, size=ROBOT.nv)
    estimates = []
    for config in CONFIGS:
        a, tau = synthesize(rng, config, q, v, phi)
        res = extract(ROBOT, q[None], v[None], a[None], tau[None], tau[None], config[None])
        estimates.append((res.rbd_observed[0], res.rbd_error[0]))
    for (m1, e1), (m2, e2) in itertools.combinations(estimates, 2):
        shared = m1 & m2
        np.testing.assert_allclose(e1[shared], e2[shared], atol=1e-8)


def test_batch_with_mixed_configurations_matches_single_samples():
    rng = np.random.default_rng(3)
    rows = []
    for k in range(40):
        config = CONFIGS[k % 16]
        q, v = random_state(rng)
        phi = rng.normal(size=ROBOT.nv)
        a, tau = synthesize(rng, config, q, v, phi)
        rows.append((q, v, a, tau, config))
    q, v, a, tau, c = (np.array(x) for x in zip(*rows))
    batch = extract(ROBOT, q, v, a, tau, tau, c)
    for k in range(0, 40, 7):
        single = extract(ROBOT, q[k:k + 1], v[k:k + 1], a[k:k + 1], tau[k:k + 1], tau[k:k + 1], c[k:k + 1])
        np.testing.assert_allclose(batch.rbd_error[k], single.rbd_error[0], atol=1e-9)


def test_near_singular_leg_gives_finite_bounded_error():
    rng = np.random.default_rng(11)
    q, v = random_state(rng)
    q[7 + 2] = 1e-4  # lf knee almost straight (outside HyQ's limits on purpose)
    dyn = RigidBodyDynamics(ROBOT)
    block = dyn.foot_jacobians(q)[0][:, 6:9]
    assert np.linalg.svd(block, compute_uv=False)[-1] < DEFAULT_GAMMA  # really near-singular
    config = np.array([False, True, True, True])  # the straight leg swings
    a = rng.normal(size=ROBOT.nv)
    tau = rng.normal(scale=30.0, size=12)
    res = extract(ROBOT, q[None], v[None], a[None], tau[None], tau[None], config[None])
    assert np.all(np.isfinite(res.rbd_error))
    # |Φ̃'| ≤ |r| / γ-scale: bounded by the regularisation, not divergent
    r = np.linalg.norm(res.residual[0])
    assert np.linalg.norm(res.rbd_error[0]) < 10 * r / DEFAULT_GAMMA


def test_eq11_operator_bases_and_leg_coupling_equal_their_textbook_forms():
    """The compiled core's J' (eq. 8, γ-clamped), eq. (11) operator and leg coupling against the
    formulas written out in numpy: (P_c J_uᵀ)⁺ P_c with the pseudo-inverse, U max(Σ, γ) Vᵀ and
    C_i = J_i,baseᵀ B_i⁻ᵀ; near-singular legs included (the clamp's branch)."""
    rng = np.random.default_rng(13)
    states = [random_state(rng)[0] for _ in range(16)]
    for k in (3, 9):
        states[k][7 + 3 * (k % 4) + 2] = 0.01 * (k % 4 - 1.5)  # a near-straight knee
    q = np.array(states)
    dyn = RigidBodyDynamics(ROBOT)
    J = np.array([dyn.foot_jacobians(x) for x in q])
    contacts = np.array(CONFIGS)
    basis = contact_invariant_bases(J, ROBOT.leg_joints)
    ops, mask = observation_operators(J, basis, contacts)
    r = rng.normal(scale=50.0, size=(len(q), ROBOT.nv))
    phi, phi_mask = observe(J, basis, contacts, r)
    C = leg_coupling(basis, ROBOT.leg_joints)
    clamped = 0
    for k, config in enumerate(contacts):
        expected = np.zeros((ROBOT.nv, ROBOT.nv))
        expected[:6, :6] = np.eye(6)
        expected[6:] = J[k].reshape(-1, ROBOT.nv)
        for i, leg in enumerate(ROBOT.leg_joints):
            cols = 6 + np.array(leg)
            U, s, Vt = np.linalg.svd(J[k, i][:, cols])
            clamped += s[-1] < DEFAULT_GAMMA
            expected[6 + 3 * i:9 + 3 * i, cols] = (U * np.maximum(s, DEFAULT_GAMMA)) @ Vt
        np.testing.assert_allclose(basis[k], expected, rtol=0, atol=1e-12)
        unconstrained = np.concatenate([np.arange(6)] + [6 + 3 * i + np.arange(3) for i in np.flatnonzero(~config)])
        P = projector(contact_jacobian(J[k], config))
        textbook = np.zeros((ROBOT.nv, ROBOT.nv))
        textbook[unconstrained] = np.linalg.pinv(P @ basis[k][unconstrained].T) @ P
        np.testing.assert_allclose(ops[k], textbook, rtol=0, atol=1e-9 * np.abs(textbook).max())
        assert np.array_equal(mask[k], np.isin(np.arange(ROBOT.nv), unconstrained))
        np.testing.assert_allclose(phi[k], ops[k] @ r[k], rtol=0, atol=1e-9 * np.abs(phi[k]).max())
        assert np.array_equal(phi_mask[k], mask[k])
        for i, leg in enumerate(ROBOT.leg_joints):
            rows = basis[k, 6 + 3 * i:9 + 3 * i]
            np.testing.assert_allclose(C[k][:, list(leg)], rows[:, :6].T @ np.linalg.inv(rows[:, 6 + np.array(leg)]).T,
                                       rtol=0, atol=1e-9 * np.abs(C[k]).max())
    assert clamped >= 2  # the clamp's branch ran


def test_samples_that_are_not_finite_are_refused_not_the_log():
    """A sample whose state or acceleration is not finite (a NaN reaching J', eq. 11's solve or
    the residual) is refused, invalid and unobserved; the chunk is not (numpy's batched SVD raised
    for all of it), and every other sample is exactly the number it has alone."""
    rng = np.random.default_rng(17)
    rows = [random_state(rng) + (rng.normal(size=ROBOT.nv), rng.normal(scale=30.0, size=12)) for _ in range(12)]
    q, v, a, tau = (np.array(x) for x in zip(*rows))
    q[2, 7 + 4] = np.nan  # a joint angle: NaN Jacobians, J' and operator
    a[5, 0] = np.inf  # the residual only
    contacts = np.array(CONFIGS[:12])
    res = extract(ROBOT, q, v, a, tau, tau, contacts)
    assert np.flatnonzero(~res.valid).tolist() == [2, 5]
    assert np.all(np.isfinite(res.rbd_error)) and not res.rbd_observed[[2, 5]].any()
    for k in np.flatnonzero(res.valid):
        alone = extract(ROBOT, q[k:k + 1], v[k:k + 1], a[k:k + 1], tau[k:k + 1], tau[k:k + 1], contacts[k:k + 1])
        np.testing.assert_array_equal(res.rbd_error[k], alone.rbd_error[0])
        np.testing.assert_array_equal(res.leg_coupling[k], alone.leg_coupling[0])


def test_a_robot_with_joints_beyond_its_legs_is_refused_not_solved():
    """J' is square only for a floating base and three joints per foot: an extra joint (an arm, a
    spine) is a one-line error, not a silently truncated eq. (11)."""
    from ciml_learning.core.batch_dynamics import BatchCoreError

    J = np.zeros((2, 4, 3, ROBOT.nv + 2))
    with pytest.raises(BatchCoreError, match="three joints"):
        contact_invariant_bases(J, ROBOT.leg_joints)
    with pytest.raises(BatchCoreError, match="three joints"):
        observe(J, np.zeros((2, ROBOT.nv + 2, ROBOT.nv + 2)), np.ones((2, 4), bool), np.zeros((2, ROBOT.nv + 2)))


def test_projector_removes_contact_forces():
    rng = np.random.default_rng(5)
    q, _ = random_state(rng)
    J = RigidBodyDynamics(ROBOT).foot_jacobians(q)
    Jc = contact_jacobian(J, np.array([True, False, True, True]))
    P = projector(Jc)
    np.testing.assert_allclose(P @ Jc.T, 0.0, atol=1e-10)
    np.testing.assert_allclose(P @ P, P, atol=1e-10)


def test_rnea_equals_crba_plus_nle():
    rng = np.random.default_rng(2)
    dyn = RigidBodyDynamics(ROBOT)
    for _ in range(10):
        q, v = random_state(rng)
        a = rng.normal(size=ROBOT.nv)
        lhs = dyn.inverse_dynamics(q, v, a)
        rhs = dyn.mass_matrix(q) @ a + dyn.nonlinear_effects(q, v)
        np.testing.assert_allclose(lhs, rhs, rtol=1e-10, atol=1e-9)


def test_actuation_and_combined_error():
    rng = np.random.default_rng(1)
    tau, u = rng.normal(size=12), rng.normal(size=12)
    gamma = actuation_error(tau, u)
    np.testing.assert_allclose(gamma, tau - u)
    q, v = random_state(rng)
    J = RigidBodyDynamics(ROBOT).foot_jacobians(q)
    basis = contact_invariant_basis(J, ROBOT.leg_joints)
    phi = rng.normal(size=18)
    S = selection_matrix(ROBOT)
    eps = combined_error(basis, phi, gamma, S)
    # ε = J'ᵀΦ̃' − SᵀΓ: M q̈ + h + ε = Sᵀu + J_cᵀλ reproduces the measured-torque dynamics
    np.testing.assert_allclose(eps[6:] + gamma, (basis.T @ phi)[6:])
    np.testing.assert_allclose(eps[:6], (basis.T @ phi)[:6])


def test_learning_inputs_drop_base_position_and_yaw():
    rng = np.random.default_rng(4)
    q, v = random_state(rng)
    a = rng.normal(size=18)
    tau, tau_dot = rng.normal(size=12), rng.normal(size=12)
    x = learning_inputs(q[None], v[None], a[None], tau[None], tau_dot[None])
    names = learning_input_names(ROBOT)
    assert x.shape == (1, 74) and len(names) == 74  # eq. (12)'s 50, then τ and τ̇
    assert x[0, names.index("tau_rh_kfe_joint")] == tau[-1] and x[0, -1] == tau_dot[-1]
    q2 = q.copy()
    q2[:3] += 1.0  # base position
    yaw = pin.Quaternion(pin.rpy.rpyToMatrix(0, 0, 0.7) @ pin.Quaternion(q[3:7]).matrix()).coeffs()
    q2[3:7] = yaw
    np.testing.assert_allclose(learning_inputs(q2[None], v[None], a[None], tau[None], tau_dot[None]), x, atol=1e-9)


def test_reference_torque_realises_the_reference_and_differentiates_within_a_contact_phase():
    from types import SimpleNamespace

    from ciml_learning.core.dynamics import ReferenceTorque

    rng = np.random.default_rng(5)
    q, v = random_state(rng, spread=0.1)
    v *= 0.1
    a = 0.1 * rng.normal(size=ROBOT.nv)
    contacts = np.array([True, False, True, True])
    e = rng.normal(size=ROBOT.nv)
    ref_torque = ReferenceTorque(ROBOT)
    tau, tau_dot = ref_torque(SimpleNamespace(t=0.0, q=q, v=v, a=a, contacts=contacts), e)
    assert np.all(np.abs(tau) < ROBOT.torque_limits), "the check below needs an unclipped τ"
    assert np.all(tau_dot == 0.0)  # first call
    # Sᵀτ realises M q̈ + h + e up to contact forces of the stance feet: the remainder lies in span(J_cᵀ)
    dyn = RigidBodyDynamics(ROBOT)
    Jc = contact_jacobian(dyn.foot_jacobians(q), contacts)
    rest = selection_matrix(ROBOT).T @ tau - (dyn.inverse_dynamics(q, v, a) + e)
    lam = np.linalg.lstsq(Jc.T, rest, rcond=None)[0]
    assert np.allclose(Jc.T @ lam, rest, atol=1e-8 * np.abs(rest).max())
    tau2, tau_dot2 = ref_torque(SimpleNamespace(t=0.004, q=q, v=v, a=1.1 * a, contacts=contacts), e)
    assert np.allclose(tau_dot2, (tau2 - tau) / 0.004)  # two calls of one schedule: their difference
    _, tau_dot3 = ref_torque(SimpleNamespace(t=0.008, q=q, v=v, a=a, contacts=~contacts | contacts), e)
    assert np.all(tau_dot3 == 0.0)  # across a change of the contact schedule


def test_reference_torque_rate_is_the_slope_over_the_period_its_command_holds():
    """τ̇_ref at t is the slope at t + Δ/2 (the command computed at t holds over [t, t + Δ]) of the
    parabola through the last three τ_ref: exact for a τ_ref quadratic in time, on a uniform grid
    and across a longer step; the backward difference would be off by c2·Δ per joint."""
    from types import SimpleNamespace

    from ciml_learning.core.dynamics import ReferenceTorque

    n = ROBOT.n_joints
    c0, c1, c2 = np.linspace(-5, 5, n), np.linspace(2, -3, n), np.linspace(40, -60, n)
    ref_torque = ReferenceTorque(ROBOT)
    ref_torque.torque = lambda q, v, a, contacts, e=None, fj=None: c0 + c1 * a[0] + c2 * a[0] ** 2  # a carries t here
    q, v = np.zeros(ROBOT.nq), np.zeros(ROBOT.nv)
    rates = {}
    for t in (0.0, 0.004, 0.008, 0.012, 0.020):
        rates[t] = ref_torque(SimpleNamespace(t=t, q=q, v=v, a=np.full(ROBOT.nv, t)))[1]
    assert np.all(rates[0.0] == 0.0)
    np.testing.assert_allclose(rates[0.004], c1 + c2 * 0.004, rtol=1e-9)  # two calls: their difference
    for t, h in ((0.008, 0.004), (0.012, 0.004), (0.020, 0.008)):
        np.testing.assert_allclose(rates[t], c1 + 2 * c2 * (t + h / 2), rtol=1e-9, atol=1e-9)


def test_dataset_extracted_in_chunks_matches_the_whole_log(tmp_path, monkeypatch):
    """pipeline.load_dataset (bags joined column by column, eq. 11 in chunks that cross bag
    boundaries) gives the numbers of the whole-log path it replaced: the bags' filtered logs
    concatenated, then one extract() of everything."""
    import functools

    from synthetic import write_synthetic_bag

    from ciml_learning.core.filters import filter_state_log
    from ciml_learning.logs import pipeline
    from ciml_learning.logs.loginputs import load_log

    bags = []
    for seed, seconds in enumerate((2.0, 1.5, 2.5)):
        bags.append(str(tmp_path / f"bag{seed}"))
        write_synthetic_bag(ROBOT, bags[-1], seconds=seconds, seed=seed)
    # whole log, as before: filter each bag, concatenate (segment ids made distinct), extract once
    logs = []
    for bag in bags:
        raw = load_log(ROBOT, bag, None)
        logs.append(filter_state_log(raw.t, raw.q, raw.v, raw.tau, raw.u, raw.contacts, fs=raw.rate_hz))
    whole = {f: np.concatenate([getattr(log, f) for log in logs]) for f in pipeline.LOG_COLUMNS}
    offsets = np.cumsum([0] + [int(log.segment.max()) + 1 for log in logs[:-1]])
    whole["segment"] = np.concatenate([log.segment + o for log, o in zip(logs, offsets)])
    n = len(whole["t"])
    reference = extract(ROBOT, whole["q"], whole["v"], whole["a"], whole["tau"], whole["u"], whole["contacts"],
                        whole["t"], whole["valid"], tau_dot=whole["tau_dot"], chunk=n,
                        effort_valid=whole["effort_valid"])

    monkeypatch.setattr(pipeline, "extract", functools.partial(extract, chunk=173))
    ds = pipeline.load_dataset(ROBOT, bags, progress=False)
    assert len(ds.targets.t) == n > 3 * 173 and ds.n_valid > 0
    np.testing.assert_array_equal(ds.bag_index, np.repeat([0, 1, 2], [len(log) for log in logs]))
    for f in pipeline.LOG_COLUMNS:
        np.testing.assert_array_equal(getattr(ds.log, f), whole[f], err_msg=f)
    for f, x in vars(reference).items():
        y = getattr(ds.targets, f)
        assert y.shape == x.shape and y.dtype == x.dtype, f
        if x.dtype == bool:
            np.testing.assert_array_equal(y, x, err_msg=f)
        else:
            np.testing.assert_allclose(y, x, rtol=1e-9, atol=1e-9 * np.nanmax(np.abs(x)), err_msg=f)
