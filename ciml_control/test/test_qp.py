"""Feedforward QP of eq. (18–21): matrices (no solver) and proxsuite solutions."""
import math

import numpy as np
import pinocchio as pin
import pytest

from ciml_control.qp import (
    FeedforwardQP,
    QPFailedError,
    build_feedforward_qp,
    friction_cone_matrix,
)
from ciml_learning.core.dynamics import RigidBodyDynamics, selection_matrix
from ciml_learning.core.errors import CimlError

G = 9.81


@pytest.fixture(scope="module")
def stance(robot):
    q = pin.neutral(robot.model)
    q[7:] = robot.standing_joints
    q[2] = 0.6
    dyn = RigidBodyDynamics(robot)
    return q, dyn.terms(q, np.zeros(robot.nv))


def _problem(robot, terms, contacts, qdd=None, eps=None, **kw):
    nv = robot.nv
    return build_feedforward_qp(terms.mass_matrix, terms.nonlinear_effects, terms.foot_jacobians,
                                np.asarray(contacts, bool), np.zeros(nv) if qdd is None else qdd,
                                np.zeros(nv) if eps is None else eps, robot.torque_limits, **kw)


def test_friction_cone_matrix_is_inscribed_octagon():
    F = friction_cone_matrix(0.5)
    assert F.shape == (9, 3)
    mu_in = 0.5 * math.cos(math.pi / 8)
    for theta in np.linspace(0, 2 * np.pi, 33):
        inside = np.array([0.99 * mu_in * np.cos(theta), 0.99 * mu_in * np.sin(theta), 1.0])
        outside = np.array([1.01 * 0.5 * np.cos(theta), 1.01 * 0.5 * np.sin(theta), 1.0])  # outside the true cone
        assert np.all(F[:8] @ inside <= 0)
        assert np.any(F[:8] @ outside > 0)
    assert F[8] @ np.array([0, 0, 1.0]) < 0  # the normal-force row


@pytest.mark.parametrize("contacts", [[1, 1, 1, 1], [1, 1, 1, 0], [0, 1, 1, 1], [1, 0, 0, 1]])
def test_matrices_reproduce_full_dynamics(robot, stance, contacts):
    """Without a solver: any u with A u = b, and λ(u) of eq. (20), satisfy eq. (3) exactly."""
    q, terms = stance
    rng = np.random.default_rng(0)
    qdd = 0.3 * rng.standard_normal(robot.nv)
    eps = 5.0 * rng.standard_normal(robot.nv)
    p = _problem(robot, terms, contacts, qdd, eps)
    n_c = sum(contacts)
    assert p.C.shape == (9 * n_c, robot.n_joints) and p.G.shape == (3 * n_c, robot.n_joints)
    S = selection_matrix(robot)
    Jc = terms.foot_jacobians[np.asarray(contacts, bool)].reshape(-1, robot.nv)
    rhs = terms.mass_matrix @ qdd + terms.nonlinear_effects + eps
    assert np.allclose(p.rhs, rhs)
    u0 = np.linalg.lstsq(p.A, p.b, rcond=None)[0]
    null = np.linalg.svd(p.A)[2][p.A.shape[0]:].T
    for z in (np.zeros(null.shape[1]), rng.standard_normal(null.shape[1]) * 10):
        u = u0 + null @ z
        lam = p.contact_forces(u).ravel()
        residual = S.T @ u + Jc.T @ lam - rhs
        if p.unrealizable == 0.0:
            assert np.linalg.norm(residual) < 1e-8 * np.linalg.norm(rhs)
        else:  # two contacts on a line: only the unrealizable moment is left over
            assert np.linalg.norm(residual) == pytest.approx(p.unrealizable, rel=1e-6)
    # inequality rows are the friction cone of λ(u): C u ≤ c_u ⇔ F λ ≤ d
    u = rng.standard_normal(robot.n_joints) * 20
    lam = p.contact_forces(u)
    F = friction_cone_matrix(0.5)
    d = np.r_[np.zeros(8), -5.0]
    lhs = np.concatenate([F @ f - d for f in lam])
    assert np.allclose(p.C @ u - p.c_u, lhs)


def test_diagonal_support_reports_unrealizable_moment(robot, stance):
    q, terms = stance
    p = _problem(robot, terms, [1, 0, 0, 1])  # lf + rh: the CoM is off that diagonal at this pose
    assert p.A.shape[0] == robot.nv - 6 - 1  # one row of Q_uᵀSᵀ is zero
    A_full = p.Q_u[6:].T
    assert np.linalg.matrix_rank(A_full) == p.A.shape[0]
    assert np.linalg.matrix_rank(np.vstack([A_full, p.A])) == p.A.shape[0]  # same row space
    assert p.unrealizable > 0.1
    full = _problem(robot, terms, [1, 1, 1, 1])
    assert full.unrealizable == 0.0 and full.A.shape[0] == 6


def test_static_stance_carries_weight(robot, stance):
    """ε = 0, q̈ = 0, q̇ = 0, four feet: Σλ_z = m g; constraints hold; eq. (19) to 1e-8."""
    q, terms = stance
    p = _problem(robot, terms, [1, 1, 1, 1])
    sol = FeedforwardQP().solve(p)
    lam = sol.contact_forces
    mg = robot.total_mass * np.linalg.norm(robot.model.gravity.linear)
    assert lam[:, 2].sum() == pytest.approx(mg, rel=1e-6)
    assert np.allclose(lam[:, :2].sum(axis=0), 0.0, atol=1e-6 * mg)
    # equality (unconstrained dynamics) to 1e-8
    assert np.max(np.abs(p.A @ sol.u - p.b)) <= 1e-8 * max(1.0, np.abs(p.b).max())
    # torque limits, unilaterality, friction octagon
    assert np.all(np.abs(sol.u) <= robot.torque_limits + 1e-9)
    assert np.all(lam[:, 2] >= 5.0 - 1e-6)
    mu_in = 0.5 * math.cos(math.pi / 8)
    for f in lam:
        for k in range(8):
            th = k * math.pi / 4
            assert math.cos(th) * f[0] + math.sin(th) * f[1] <= mu_in * f[2] + 1e-6
    # the full dynamics with these torques and forces
    S = selection_matrix(robot)
    Jc = terms.foot_jacobians.reshape(-1, robot.nv)
    assert np.allclose(S.T @ sol.u + Jc.T @ lam.ravel(), p.rhs, atol=1e-6)
    # W_u = I: the minimum-norm torque among all that satisfy the equality and constraints
    u0 = np.linalg.lstsq(p.A, p.b, rcond=None)[0]
    assert np.linalg.norm(sol.u) <= np.linalg.norm(u0) + 1e-6


def test_model_error_changes_contact_forces(robot, stance):
    """ε adds a generalized force the contacts must carry: +50 N on the base z → Σλ_z + 50 N."""
    q, terms = stance
    eps = np.zeros(robot.nv)
    eps[2] = 50.0  # base frame z = world z at identity orientation
    qp = FeedforwardQP()
    base = qp.solve(_problem(robot, terms, [1, 1, 1, 1])).contact_forces[:, 2].sum()
    more = qp.solve(_problem(robot, terms, [1, 1, 1, 1], eps=eps)).contact_forces[:, 2].sum()
    assert more - base == pytest.approx(50.0, rel=1e-6)


def test_friction_cone_limits_lateral_acceleration(robot, stance):
    """0.25 g sideways: feasible with μ = 0.5 (Σλ_y = m a_y), infeasible with μ = 0.1."""
    q, terms = stance
    qdd = np.zeros(robot.nv)
    qdd[1] = 0.25 * G
    sol = FeedforwardQP().solve(_problem(robot, terms, [1, 1, 1, 1], qdd))
    lam = sol.contact_forces
    m_ay = (terms.mass_matrix @ qdd)[1]
    assert lam[:, 1].sum() == pytest.approx(m_ay, rel=1e-6)
    assert np.all(np.abs(lam[:, 1]) <= 0.5 * lam[:, 2] + 1e-6)
    with pytest.raises(QPFailedError):
        FeedforwardQP().solve(_problem(robot, terms, [1, 1, 1, 1], qdd, mu=0.1))


@pytest.mark.parametrize("kind", ["normal_force", "torque_limit"])
def test_infeasible_problem_raises_not_torque(robot, stance, kind):
    q, terms = stance
    if kind == "normal_force":
        p = _problem(robot, terms, [1, 1, 1, 1], f_min=400.0)  # 4·400 N > m g
    else:
        p = build_feedforward_qp(terms.mass_matrix, terms.nonlinear_effects, terms.foot_jacobians,
                                 np.ones(4, bool), np.zeros(robot.nv), np.zeros(robot.nv),
                                 np.full(robot.n_joints, 2.0))  # 2 Nm cannot hold 87 kg
    with pytest.raises(QPFailedError) as info:
        FeedforwardQP().solve(p)
    assert isinstance(info.value, CimlError)
    assert info.value.problem is p


def test_non_finite_problem_raises(robot, stance):
    q, terms = stance
    eps = np.zeros(robot.nv)
    eps[3] = np.nan
    with pytest.raises(QPFailedError):
        FeedforwardQP().solve(_problem(robot, terms, [1, 1, 1, 1], eps=eps))


def test_warm_started_solver_reused_per_size(robot, stance):
    q, terms = stance
    qp = FeedforwardQP()
    a = qp.solve(_problem(robot, terms, [1, 1, 1, 1]))
    b = qp.solve(_problem(robot, terms, [1, 1, 1, 1]))
    assert len(qp._solvers) == 1
    assert np.allclose(a.u, b.u, atol=1e-6)
    assert b.iterations <= a.iterations
    qp.solve(_problem(robot, terms, [1, 1, 1, 0]))
    assert len(qp._solvers) == 2
    c = qp.solve(_problem(robot, terms, [1, 1, 1, 1]))
    assert np.allclose(a.u, c.u, atol=1e-6)


def test_cost_change_reaches_warm_started_solver(robot, stance):
    q, terms = stance
    W = np.diag(np.linspace(1.0, 5.0, robot.n_joints))
    qp = FeedforwardQP()
    qp.solve(_problem(robot, terms, [1, 1, 1, 1]))
    warm = qp.solve(_problem(robot, terms, [1, 1, 1, 1], W_u=W))
    cold = FeedforwardQP().solve(_problem(robot, terms, [1, 1, 1, 1], W_u=W))
    assert np.allclose(warm.u, cold.u, atol=1e-6)
    assert not np.allclose(warm.u, qp.solve(_problem(robot, terms, [1, 1, 1, 1])).u, atol=1e-3)
