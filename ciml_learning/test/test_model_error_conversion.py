"""conversions.model_error_arrays: the one decoder of ciml_msgs/ModelError (the controller's
prediction reader and the learner's measurement reader both use it). No DDS needed."""
from __future__ import annotations

import numpy as np
import pytest

from ciml_learning.core import conversions as cv
from ciml_learning.core.conversions import ConversionError, model_error_arrays
from ciml_learning.core.robot import load_robot

ROBOT = load_robot()
NR, NJ = len(ROBOT.rbd_error_names), ROBOT.n_joints


def _message(rng, variances=True):
    phi, gamma = rng.normal(size=NR), rng.normal(size=NJ)
    obs_r, obs_a = rng.uniform(size=NR) > 0.5, rng.uniform(size=NJ) > 0.5
    var_r, var_a, var_g = ((rng.uniform(size=NR), rng.uniform(size=NJ), rng.uniform(size=ROBOT.nv)) if variances
                           else (None, None, None))
    msg = cv.model_error_msg(ROBOT, 7, "sgpr", phi, obs_r, gamma, obs_a, var_r, var_a, var_g)
    return msg, (phi, obs_r, var_r, gamma, obs_a, var_a, var_g)


def _shuffle(msg, rng) -> None:
    """Reorder every named array of the message consistently."""
    pr, pa = rng.permutation(NR), rng.permutation(NJ)
    for f in ("rbd_names", "rbd_error", "rbd_observed", "rbd_variance"):
        setattr(msg, f, [getattr(msg, f)[i] for i in pr])
    for f in ("actuation_names", "actuation_error", "actuation_observed", "actuation_variance"):
        setattr(msg, f, [getattr(msg, f)[i] for i in pa])
    if len(msg.generalized_variance):  # base entries in rbd_names' order of them, then the joints'
        g = msg.generalized_variance
        msg.generalized_variance = [g[i] for i in pr if i < 6] + [g[6 + i] for i in pa]


def test_decodes_every_field_by_name_in_the_robots_orders():
    rng = np.random.default_rng(3)
    msg, (phi, obs_r, var_r, gamma, obs_a, var_a, var_g) = _message(rng)
    _shuffle(msg, rng)
    e = model_error_arrays(ROBOT, msg)
    assert e.source == "sgpr"
    np.testing.assert_array_equal(e.rbd_error, phi)
    np.testing.assert_array_equal(e.rbd_observed, obs_r)
    np.testing.assert_array_equal(e.rbd_variance, var_r)
    np.testing.assert_array_equal(e.actuation_error, gamma)
    np.testing.assert_array_equal(e.actuation_observed, obs_a)
    np.testing.assert_array_equal(e.actuation_variance, var_a)
    np.testing.assert_array_equal(e.generalized_variance, var_g)


def test_missing_variances_are_infinite():
    msg, _ = _message(np.random.default_rng(4))
    msg.rbd_variance, msg.actuation_variance, msg.generalized_variance = [], [], []
    e = model_error_arrays(ROBOT, msg)
    assert e.rbd_variance.shape == (NR,) and np.all(np.isinf(e.rbd_variance))
    assert e.actuation_variance.shape == (NJ,) and np.all(np.isinf(e.actuation_variance))
    assert e.generalized_variance is None  # the gate then works in Φ̃' (a producer that does not send it)
    # a message of the definition before the field (a log read with its own schema)
    from types import SimpleNamespace
    older = SimpleNamespace(**{f: getattr(msg, f) for f in msg.get_fields_and_field_types()
                               if f != "generalized_variance"})
    assert model_error_arrays(ROBOT, older).generalized_variance is None


@pytest.mark.parametrize("field, value, match", [
    ("rbd_error", float("nan"), "non-finite"),
    ("actuation_error", float("inf"), "non-finite"),
    ("rbd_variance", -1.0, "rbd_variance"),
    ("rbd_variance", float("nan"), "rbd_variance"),
    ("actuation_variance", float("inf"), "actuation_variance"),
    ("generalized_variance", -1.0, "generalized_variance"),
    ("generalized_variance", float("nan"), "generalized_variance"),
])
def test_rejects_non_finite_values_and_negative_variances(field, value, match):
    msg, _ = _message(np.random.default_rng(5))
    setattr(msg, field, [value] + list(getattr(msg, field))[1:])
    with pytest.raises(ConversionError, match=match):
        model_error_arrays(ROBOT, msg)


@pytest.mark.parametrize("field, names", [
    ("rbd_names", lambda n: ["nope"] + n[1:]),              # unknown
    ("rbd_names", lambda n: [n[1]] + n[1:]),                # repeated (and one missing)
    ("rbd_names", lambda n: n + ["base_fx"]),               # repeated, extra entry
    ("actuation_names", lambda n: n[:-1] + [n[0]]),         # repeated joint
    ("actuation_names", lambda n: n[:-1] + ["xx_joint"]),   # unknown joint
    ("actuation_names", lambda n: n[:-1]),                  # missing joint
])
def test_rejects_wrong_names_with_a_conversion_error(field, names):
    msg, _ = _message(np.random.default_rng(6))
    setattr(msg, field, names(list(getattr(msg, field))))
    with pytest.raises(ConversionError, match="names"):
        model_error_arrays(ROBOT, msg)


@pytest.mark.parametrize("field, match", [
    ("rbd_error", "rbd_error"), ("actuation_error", "actuation_error"),
    ("rbd_observed", "observed"), ("actuation_observed", "observed"),
    ("rbd_variance", "rbd_variance"), ("actuation_variance", "actuation_variance"),
    ("generalized_variance", "generalized_variance"),
])
def test_rejects_wrong_sizes(field, match):
    msg, _ = _message(np.random.default_rng(7))
    setattr(msg, field, list(getattr(msg, field))[:-1])
    with pytest.raises(ConversionError, match=match):
        model_error_arrays(ROBOT, msg)


def test_torque_command_decoded_in_joint_order_and_checked():
    """conversions.torque_command_arrays (the bridge's and the state filter's reader) on a command
    whose joints are listed in another order; wrong lengths, non-finite or negative gains rejected."""
    rng = np.random.default_rng(3)
    rows = rng.uniform(0.5, 2.0, size=(6, NJ))
    cmd = cv.TorqueCommandArrays(1, *rows)
    msg = cv.torque_command_msg(ROBOT, 7, cmd)
    order = rng.permutation(NJ)
    msg.joint_names = [msg.joint_names[i] for i in order]
    for f in cv.TORQUE_COMMAND_FIELDS:
        setattr(msg, f, np.asarray(getattr(msg, f))[order])
    out = cv.torque_command_arrays(ROBOT, msg)
    assert out.mode == 1
    for f, row in zip(cv.TORQUE_COMMAND_FIELDS, rows):
        np.testing.assert_array_equal(getattr(out, f), row)
    for f, value, error in (("damping", -1.0, "negative"), ("feedforward", np.nan, "non-finite")):
        bad = cv.torque_command_msg(ROBOT, 7, cmd)
        values = np.asarray(getattr(bad, f)).copy()
        values[2] = value
        setattr(bad, f, values)
        with pytest.raises(ConversionError, match=error):
            cv.torque_command_arrays(ROBOT, bad)
    short = cv.torque_command_msg(ROBOT, 7, cmd)
    short.stiffness = np.asarray(short.stiffness)[:-1]
    with pytest.raises(ConversionError, match="stiffness: expected"):
        cv.torque_command_arrays(ROBOT, short)
