"""RobotReference / ModelError ↔ numpy (no DDS needed)."""
import numpy as np
import pytest

from ciml_control.conversions import reference_msg, reference_point
from ciml_control.references import make_reference, standing_configuration
from ciml_learning.core import conversions as cv
from ciml_learning.core.dynamics import RigidBodyDynamics, selection_matrix
from ciml_learning.core.errors import CimlError
from ciml_learning.core.extraction import combined_error
from ciml_learning.core.projection import contact_invariant_basis
from ciml_learning.core.robot import load_robot

ROBOT = load_robot()


def test_reference_round_trip_by_name():
    ref = make_reference(ROBOT, "trot_35", standing_configuration(ROBOT, 0.002)).sample(3.37)
    msg = reference_msg(ROBOT, 3_370_000_000, ref)
    # reorder joints and feet in the message: the reader matches by name
    order = np.arange(ROBOT.n_joints)[::-1]
    for f in ("position", "velocity", "acceleration"):
        setattr(msg, f, [getattr(msg, f)[i] for i in order])
    msg.joint_names = [msg.joint_names[i] for i in order]
    msg.foot_names = msg.foot_names[::-1]
    msg.in_contact = msg.in_contact[::-1]
    back = reference_point(ROBOT, msg)
    assert back.t == pytest.approx(3.37) and back.motion == "trot_35" and back.phase == pytest.approx(ref.phase)
    assert np.allclose(back.q, ref.q) and np.allclose(back.v, ref.v) and np.allclose(back.a, ref.a)
    assert np.array_equal(back.contacts, ref.contacts)
    msg.velocity = [float("nan")] + list(msg.velocity[1:])
    with pytest.raises(CimlError):
        reference_point(ROBOT, msg)


def test_model_error_to_epsilon():
    rng = np.random.default_rng(0)
    phi, gamma = rng.standard_normal(18), rng.standard_normal(ROBOT.n_joints)
    msg = cv.model_error_msg(ROBOT, 0, "sgpr", phi, np.ones(18, bool), gamma, np.ones(ROBOT.n_joints, bool))
    perm = rng.permutation(18)
    msg.rbd_names = [msg.rbd_names[i] for i in perm]
    msg.rbd_error = [msg.rbd_error[i] for i in perm]
    back = cv.model_error_arrays(ROBOT, msg)
    phi_back, gamma_back = back.rbd_error, back.actuation_error
    assert np.allclose(phi_back, phi) and np.allclose(gamma_back, gamma)
    q = standing_configuration(ROBOT)
    basis = contact_invariant_basis(RigidBodyDynamics(ROBOT).foot_jacobians(q), ROBOT.leg_joints)
    S = selection_matrix(ROBOT)
    eps = combined_error(basis, phi_back, gamma_back, S)
    assert np.allclose(eps, basis.T @ phi - S.T @ gamma)  # eq. (17)
    msg.rbd_names = msg.rbd_names[:-1] + ["foot_xx_z"]
    with pytest.raises(cv.ConversionError, match="names"):
        cv.model_error_arrays(ROBOT, msg)
