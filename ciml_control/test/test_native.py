"""The controller's C++ core (ciml_control.native) and the QP in the equality's null space."""
import ctypes
import types

import numpy as np
import pinocchio as pin
import proxsuite
import pytest

from ciml_control import native
from ciml_control.compiled.control_step import desired_terms
from ciml_control.compiled.feedforward_qp import eliminate_equality
from ciml_control.controller import IdController
from ciml_control.qp import FeedforwardQP, build_feedforward_qp
from ciml_control.references import make_reference, standing_configuration


def _terms(robot, q, v):
    """The core's (M, h, J) at (q, v) through the compiled entry point."""
    dyn = native.Dynamics(robot)
    fns = native.function_table()
    nv, nf = robot.nv, robot.n_feet
    M, h, J = np.zeros((nv, nv)), np.zeros(nv), np.zeros((nf, 3, nv))
    key = np.zeros(robot.nq + nv + 1)
    desired_terms(fns, dyn.handle, q, v, key, M, h, J)
    return M, h, J


def test_core_terms_equal_pinocchio(robot):
    """M (upper triangle), h and the foot Jacobians of the core equal Pinocchio's Python
    bindings at random states (the same model, passed as Pinocchio's own archive)."""
    rng = np.random.default_rng(3)
    model = robot.model
    data = model.createData()
    for _ in range(10):
        q = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        v = rng.standard_normal(model.nv)
        M, h, J = _terms(robot, q, v)
        pin.computeAllTerms(model, data, q, v)
        pin.updateFramePlacements(model, data)
        np.testing.assert_allclose(np.triu(M), np.triu(data.M), rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(h, data.nle, rtol=1e-12, atol=1e-12)
        q0 = pin.randomConfiguration(model, -np.ones(model.nq), np.ones(model.nq))
        dyn, e = native.Dynamics(robot), np.zeros(model.nv)
        native.library().ciml_difference(*(ctypes.c_void_p(a) for a in (dyn.handle, q0.ctypes.data, q.ctypes.data,
                                                                         e.ctypes.data)))
        np.testing.assert_allclose(e, pin.difference(model, q0, q), rtol=1e-12, atol=1e-12)
        for i, f in enumerate(robot.foot_frame_ids):
            np.testing.assert_allclose(J[i], pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3],
                                       rtol=1e-12, atol=1e-12)


def test_core_refuses_a_model_it_cannot_load(robot):
    fake = types.SimpleNamespace(model=types.SimpleNamespace(saveToString=lambda: "not an archive"),
                                 foot_frame_ids=robot.foot_frame_ids)
    with pytest.raises(native.NativeCoreError, match="could not load"):
        native.Dynamics(fake)


def test_eliminate_equality_parametrises_the_equality():
    """u₀ solves A u = b with least norm, N is an orthonormal basis of null(A), and the
    reduced cost is the original one along u₀ + N z."""
    rng = np.random.default_rng(0)
    n, m, nc = 12, 7, 9
    A, b = rng.standard_normal((m, n)), rng.standard_normal(m)
    W = rng.standard_normal((n, n))
    H, g = W @ W.T + np.eye(n), rng.standard_normal(n)
    C, c_u = rng.standard_normal((nc, n)), rng.standard_normal(nc)
    l, lb, ub = np.full(nc, -1e20), -np.ones(n), np.ones(n)
    u0, N, H_z, g_z, C_z, l_z, c_z = eliminate_equality(A, b, H, g, C, l, c_u, lb, ub)
    np.testing.assert_allclose(A @ u0, b, atol=1e-12)
    np.testing.assert_allclose(u0, np.linalg.pinv(A) @ b, atol=1e-12)
    np.testing.assert_allclose(A @ N, 0.0, atol=1e-12)
    np.testing.assert_allclose(N.T @ N, np.eye(n - m), atol=1e-12)
    z = rng.standard_normal(n - m)
    u = u0 + N @ z
    cost = 0.5 * u @ H @ u + g @ u
    np.testing.assert_allclose(0.5 * z @ H_z @ z + g_z @ z + 0.5 * u0 @ H @ u0 + g @ u0, cost, rtol=1e-12)
    np.testing.assert_allclose(C_z @ z - np.r_[C @ u - C @ u0, u - u0], 0.0, atol=1e-12)
    np.testing.assert_allclose(c_z, np.r_[c_u - C @ u0, ub - u0], atol=1e-12)


def test_reduced_qp_gives_the_full_qps_answer(robot):
    """Along a trot (two- and four-foot support): the torque of the QP solved in the
    equality's null space equals proxsuite's answer to the full QP over u with eq. (19)
    as equality rows (the formulation of the paper), to 1e-6 Nm."""
    q_stand = standing_configuration(robot, 0.002)
    ref = make_reference(robot, "trot_35", q_stand)
    ctrl = IdController(robot)
    qp = FeedforwardQP()
    rng = np.random.default_rng(2)
    worst = 0.0
    sizes = set()
    for k in range(0, 250, 5):
        p = ref.sample(1.0 + k / 250)
        M, h, J = ctrl.desired_terms(p)
        eps = rng.normal(0.0, 5.0, robot.nv)
        prob = build_feedforward_qp(M, h, J, p.contacts, p.a, eps, robot.torque_limits)
        full = proxsuite.proxqp.dense.QP(robot.n_joints, len(prob.b), len(prob.l), True)
        full.settings.eps_abs, full.settings.eps_rel, full.settings.verbose = 1e-10, 0.0, False
        full.init(prob.H, prob.g, prob.A, prob.b, prob.C, prob.l, prob.c_u, prob.lb, prob.ub)
        full.solve()
        assert full.results.info.status == proxsuite.proxqp.QPSolverOutput.PROXQP_SOLVED
        worst = max(worst, float(np.abs(qp.solve(prob).u - full.results.x).max()))
        sizes.add(prob.A.shape[0])
    assert sizes == {6, 11}  # four and two feet
    assert worst < 1e-6
