"""The compiled control step (IdController.compute → compiled.control_step → the C++ core)
computes what its specification, ciml_control.specification (eq. 18–24 in numpy), computes."""
import numpy as np
import pinocchio as pin
import pytest

from ciml_control import specification
from ciml_control.controller import IdController
from ciml_control.feedback import FeedbackGains
from ciml_control.references import ReferencePoint, make_reference

TOL = 1e-8
"""[Nm] measured: the two paths' torques agree to 6e-11 (the QP solved in eq. 19's null space
vs the full QP over u, both to proxsuite's eps_abs; the feedback to ~1e-12)."""

CONTACT_SETS = [(1, 1, 1, 1), (1, 1, 1, 0), (0, 1, 1, 1), (1, 0, 0, 1), (0, 1, 1, 0), (1, 1, 0, 0), (0, 0, 1, 0),
                (0, 0, 0, 0)]


def _compare(robot, ctrl, gains, q, v, contacts, ref, eps, **kw):
    out = ctrl.compute(q, v, contacts, ref, eps)
    spec = specification.control_step(robot, gains, q, v, contacts, ref.q, ref.v, ref.a, ref.contacts, eps, **kw)
    assert out.qp_failed == (not spec.qp_solved)
    assert out.epsilon_rejected == spec.epsilon_rejected
    np.testing.assert_allclose(out.feedforward, spec.u_ff, rtol=0, atol=TOL)
    np.testing.assert_allclose(out.feedback_linearization, spec.u_lin, rtol=0, atol=TOL)
    np.testing.assert_allclose(out.contact_forces, spec.contact_forces, rtol=0, atol=1e-4)  # N, ∝ 1/‖J‖
    return out


@pytest.mark.parametrize("feedback_contacts", ["reference", "measured"])
def test_compiled_step_equals_the_specification_along_a_trot(robot, q_stand, feedback_contacts):
    """Random perturbed states along trot_35 (two- and four-foot support) with random ε and
    random measured contacts: the same u_ff, u_fb,lin and planned forces."""
    gains = FeedbackGains.default(robot, joint_lin_kp=40.0, joint_lin_kd=4.0)
    ctrl = IdController(robot, gains=gains, feedback_contacts=feedback_contacts)
    ref = make_reference(robot, "trot_35", q_stand)
    rng = np.random.default_rng(11)
    sizes = set()
    for k in range(12):
        p = ref.sample(1.0 + 0.037 * k)
        q = pin.integrate(robot.model, p.q, 0.02 * rng.standard_normal(robot.nv))
        v = p.v + 0.2 * rng.standard_normal(robot.nv)
        contacts = rng.random(robot.n_feet) < 0.7
        eps = rng.normal(0.0, 5.0, robot.nv)
        out = _compare(robot, ctrl, gains, q, v, contacts, p, eps, feedback_contacts=feedback_contacts)
        assert not out.qp_failed
        sizes.add(int(np.count_nonzero(p.contacts)))
    assert sizes == {2, 4}


@pytest.mark.parametrize("contacts", CONTACT_SETS)
def test_compiled_step_equals_the_specification_on_contact_subsets(robot, q_stand, contacts):
    """Every kind of reference contact set (four, three, diagonal and lateral pairs, one, none;
    rank-deficient eq. 19 and the QP fallback included) at random states, references and ε."""
    gains = FeedbackGains.default(robot, joint_lin_kp=40.0, joint_lin_kd=4.0)
    ctrl = IdController(robot, gains=gains)
    rng = np.random.default_rng(sum(c << i for i, c in enumerate(contacts)))
    for _ in range(3):
        ref = ReferencePoint(t=0.0, q=pin.integrate(robot.model, q_stand, 0.05 * rng.standard_normal(robot.nv)),
                             v=0.1 * rng.standard_normal(robot.nv), a=0.5 * rng.standard_normal(robot.nv),
                             contacts=np.array(contacts, bool), phase=0.0, motion="random")
        q = pin.integrate(robot.model, ref.q, 0.02 * rng.standard_normal(robot.nv))
        v = ref.v + 0.2 * rng.standard_normal(robot.nv)
        _compare(robot, ctrl, gains, q, v, ref.contacts, ref, rng.normal(0.0, 2.0, robot.nv))


def test_non_finite_epsilon_and_qp_failure_follow_the_specification(robot, q_stand):
    """ε with a NaN is rejected (nominal model) on both paths; an infeasible QP (f_min 400 N
    on four feet > m g) gives the specification's fallback, the clipped static torque."""
    gains = FeedbackGains.default(robot)
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    rng = np.random.default_rng(5)
    q = pin.integrate(robot.model, ref.q, 0.02 * rng.standard_normal(robot.nv))
    v = 0.2 * rng.standard_normal(robot.nv)
    eps = rng.normal(0.0, 5.0, robot.nv)
    eps[4] = np.nan
    out = _compare(robot, IdController(robot, gains=gains), gains, q, v, ref.contacts, ref, eps)
    assert out.epsilon_rejected
    failing = IdController(robot, gains=gains, f_min=400.0)
    out = _compare(robot, failing, gains, q, v, ref.contacts, ref, np.zeros(robot.nv), f_min=400.0)
    assert out.qp_failed and failing.qp_failures == 1
