"""The controller's trust law for the learned model error ε (ciml_control.trust): no rclpy."""
from __future__ import annotations

import numpy as np
import pytest

from ciml_control.trust import TrustedEpsilonFunction, TrustLaw
from ciml_learning.core.dynamics import RigidBodyDynamics, selection_matrix
from ciml_learning.core.extraction import combined_error
from ciml_learning.core.projection import contact_invariant_basis
from ciml_learning.core.robot import load_robot
from ciml_learning.learning.models import default_scaling

ROBOT = load_robot()
MG = ROBOT.total_mass * 9.81


def _basis():
    q = ROBOT.neutral_configuration().copy()
    q[2], q[7:] = 0.6, ROBOT.standing_joints
    return contact_invariant_basis(RigidBodyDynamics(ROBOT).foot_jacobians(q), ROBOT.leg_joints)


def test_confident_physical_prediction_passes_unchanged():
    law = TrustLaw(ROBOT)
    rng = np.random.default_rng(0)
    phi, gamma = rng.normal(scale=5.0, size=18), rng.normal(scale=1.0, size=12)
    basis = _basis()
    out = law.apply(phi, np.zeros(18), gamma, np.zeros(12), basis)
    np.testing.assert_allclose(out.epsilon, combined_error(basis, phi, gamma, selection_matrix(ROBOT)), atol=1e-12)
    assert out.n_gated == 0 and out.n_clipped == 0


def test_variance_above_the_prior_is_gated_entry_by_entry():
    law = TrustLaw(ROBOT)
    _, _, out_scale = default_scaling(ROBOT)
    rbd = np.zeros(ROBOT.nv)
    rbd[2] = 60.0                      # base fz, confident
    rbd[8] = 5.0                       # a knee, uncertain
    var = np.zeros(ROBOT.nv)
    var[8] = 1.01 * out_scale[8] ** 2  # just above the prior variance of that entry
    gamma = np.full(12, 2.0)
    gamma_var = np.zeros(12)
    gamma_var[0] = 4.0 * out_scale[ROBOT.nv] ** 2
    out = law.apply(rbd, var, gamma, gamma_var)           # generalized coordinates (headless)
    assert list(np.flatnonzero(out.gated)) == [8, ROBOT.nv + 0]
    expected = rbd.copy()
    expected[8] = 0.0
    g = gamma.copy()
    g[0] = 0.0
    np.testing.assert_allclose(out.epsilon, expected - selection_matrix(ROBOT).T @ g)
    # at exactly the prior variance the entry is still trusted; a looser ratio trusts more
    var[8] = out_scale[8] ** 2
    assert not TrustLaw(ROBOT).apply(rbd, var, gamma, np.zeros(12)).gated.any()
    var[8] = 3.0 * out_scale[8] ** 2
    assert not TrustLaw(ROBOT, max_variance_ratio=4.0).apply(rbd, var, gamma, np.zeros(12)).gated.any()
    with pytest.raises(ValueError):
        TrustLaw(ROBOT, max_variance_ratio=0.0)


def test_epsilon_is_clipped_to_the_robots_physics_and_never_nan():
    law = TrustLaw(ROBOT)
    phi = np.zeros(18)
    phi[2] = 1e6                        # a poisoned model: 1e6 N on the base
    gamma = np.zeros(12)
    gamma[5] = -1e4
    out = law.apply(phi, np.zeros(18), gamma, np.zeros(12), _basis())
    assert out.epsilon[2] == pytest.approx(MG) and out.clipped[2]
    assert np.all(np.abs(out.epsilon) <= law.bound + 1e-9)
    assert out.epsilon[6 + 5] == pytest.approx(ROBOT.torque_limits[5])   # −SᵀΓ: +1e4 clipped to the limit
    nan = law.apply(np.full(18, np.nan), np.zeros(18), np.full(12, np.inf), np.zeros(12), _basis())
    assert np.all(nan.epsilon == 0.0) and nan.gated.all()


def test_headless_wrapper_applies_the_same_law_and_counts():
    class Model:  # model_epsilon.EpsilonFunction's interface: predict(ref) → (Φ̃, var, Γ, var)
        model_set = object()

        def __init__(self, var):
            self.var = var

        def predict(self, ref):
            rbd = np.zeros(ROBOT.nv)
            rbd[2] = 2e3
            return rbd, np.full(ROBOT.nv, self.var), np.ones(12), np.zeros(12)

    fn = TrustedEpsilonFunction(ROBOT, Model(0.0))
    eps = fn(None)
    assert eps[2] == pytest.approx(MG) and fn.counts == {"epsilon_gated": 0, "epsilon_clipped": 1, "steps": 1}
    fn = TrustedEpsilonFunction(ROBOT, Model(1e9))
    assert fn(None)[2] == 0.0 and fn.counts["epsilon_gated"] == 1
    # an identified physical model (no variance): the clip only
    fn = TrustedEpsilonFunction(ROBOT, lambda ref: np.full(ROBOT.nv, 1e5))
    np.testing.assert_allclose(fn(None), TrustLaw(ROBOT).bound)
    assert fn.counts["epsilon_clipped"] == 1 and fn.counts["epsilon_gated"] == 0
