"""The compiled batch core (core.batch_dynamics) against Pinocchio called from Python per sample:
the same algorithms on the same model, so the same numbers to rounding."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from ciml_learning.core.batch_dynamics import BatchCoreError
from ciml_learning.core.profile import load_profile
from ciml_learning.core.robot import load_robot

RTOL, ATOL = 1e-10, 1e-9


def _samples(robot, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = np.array([pin.randomConfiguration(robot.model, -np.ones(robot.nq), np.ones(robot.nq)) for _ in range(n)])
    q[:, :3] = rng.normal(0.0, 1.0, (n, 3))
    return q, rng.normal(0.0, 2.0, (n, robot.nv)), rng.normal(0.0, 5.0, (n, robot.nv))


@pytest.fixture(scope="module", params=["hyq", "go1"])
def robot(request):
    return load_robot() if request.param == "hyq" else load_profile("go1").robot()


def test_inverse_dynamics_and_foot_jacobians_equal_pinocchio_per_sample(robot):
    q, v, a = _samples(robot, 40, 1)
    tau, jac = robot.batch.inverse_dynamics(q, v, a)
    data = robot.model.createData()
    for k in range(len(q)):
        np.testing.assert_allclose(tau[k], pin.rnea(robot.model, data, q[k], v[k], a[k]), rtol=RTOL, atol=ATOL)
        pin.computeJointJacobians(robot.model, data, q[k])
        pin.updateFramePlacements(robot.model, data)
        for i, f in enumerate(robot.foot_frame_ids):
            J = pin.getFrameJacobian(robot.model, data, f, pin.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(jac[k, i], J[:3], rtol=RTOL, atol=ATOL)


def test_regressors_equal_pinocchio_per_sample(robot):
    q, v, a = _samples(robot, 30, 2)
    jac, Y, D = robot.batch.regressors(q, v, a)
    data = robot.model.createData()
    for k in range(len(q)):
        Yk = pin.computeJointTorqueRegressor(robot.model, data, q[k], v[k], a[k])
        np.testing.assert_allclose(Y[k], Yk, rtol=RTOL, atol=ATOL)
        pin.computeRNEADerivatives(robot.model, data, q[k], v[k], a[k])
        np.testing.assert_allclose(D[k], data.dtau_dq, rtol=RTOL, atol=ATOL)
    np.testing.assert_allclose(jac, robot.batch.inverse_dynamics(q, v, a)[1], rtol=0, atol=0)


def test_jacobian_variation_products_equal_pinocchio_per_item(robot):
    q, _, _ = _samples(robot, 10, 3)
    rng = np.random.default_rng(4)
    sample = rng.integers(0, len(q), 25)
    foot = rng.integers(0, robot.n_feet, 25)
    dof = np.array([6 + robot.leg_joints[f][rng.integers(0, 3)] for f in foot])
    lam = rng.normal(0.0, 50.0, (25, 3))
    out = robot.batch.jacobian_variation_products(q, sample, foot, dof, lam)
    data = robot.model.createData()
    for i in range(25):
        pin.computeJointJacobiansTimeVariation(robot.model, data, q[sample[i]], np.eye(robot.nv)[dof[i]])
        frame = robot.foot_frame_ids[foot[i]]
        dJ = pin.getFrameJacobianTimeVariation(robot.model, data, frame, pin.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(out[i], dJ[:3].T @ lam[i], rtol=RTOL, atol=ATOL)


def test_bad_shapes_and_indices_are_refused():
    robot = load_robot()
    q, v, a = _samples(robot, 3, 5)
    with pytest.raises(BatchCoreError, match="v must be N"):
        robot.batch.inverse_dynamics(q, v[:, :5], a)
    with pytest.raises(BatchCoreError, match="rows"):
        robot.batch.regressors(q, v[:2], a)
    with pytest.raises(BatchCoreError, match="status -2"):
        robot.batch.jacobian_variation_products(q, [3], [0], [6], np.zeros(3))  # sample 3 of 3
    with pytest.raises(BatchCoreError, match="status -2"):
        robot.batch.jacobian_variation_products(q, [0], [robot.n_feet], [6], np.zeros(3))
    assert robot.batch.inverse_dynamics(q[:0], v[:0], a[:0])[0].shape == (0, robot.nv)


def test_a_robot_pickles_after_its_batch_core_was_used():
    """Robots go to joblib and Dask workers by pickle: the core's handle stays behind and is rebuilt."""
    import pickle

    robot = load_robot()
    q, v, a = _samples(robot, 2, 6)
    tau = robot.batch.inverse_dynamics(q, v, a)[0]
    copy = pickle.loads(pickle.dumps(robot))
    assert "batch" not in vars(copy)
    np.testing.assert_array_equal(copy.batch.inverse_dynamics(q, v, a)[0], tau)
