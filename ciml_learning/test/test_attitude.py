"""The attitude filter (estimation.AttitudeFilter, estimate_orientation) on signals made here:
a tilted IMU at rest, a rocking motion whose gyro and accelerometer readings are exact, a gyro
bias, bad input. The end-to-end check on a simulated go1 log is test/test_imu_orientation.py."""
import numpy as np
import pinocchio as pin
import pytest

from ciml_learning.core.estimation import (
    ATTITUDE_KP,
    GRAVITY,
    AttitudeFilter,
    EstimationError,
    estimate_orientation,
)


def _tilt_deg(R_true: np.ndarray, quat_est: np.ndarray) -> float:
    """Angle between the true and the estimated "up" in the IMU frame [deg] (yaw is not observable)."""
    up_est = pin.Quaternion(quat_est).matrix()[2]
    return float(np.degrees(np.arccos(np.clip(R_true[2] @ up_est, -1.0, 1.0))))


def _rocking(t: np.ndarray, amp: float = 0.2, hz: float = 1.0):
    """Roll φ(t) = amp sin(2π hz t), pitch θ(t) = amp/2 sin(2π hz t + 1) about a fixed point: the
    exact gyro (body rates) and accelerometer (gravity only) of an IMU that rotates in place."""
    R = np.array([pin.rpy.rpyToMatrix(amp * np.sin(2 * np.pi * hz * tk), 0.5 * amp * np.sin(2 * np.pi * hz * tk + 1),
                                      0.3 * tk) for tk in t])
    gyro = np.array([pin.log3(R[k].T @ R[k + 1]) / (t[k + 1] - t[k]) for k in range(len(t) - 1)])
    gyro = np.vstack([gyro[:1], 0.5 * (gyro[1:] + gyro[:-1]), gyro[-1:]])  # body rate at the samples
    accel = np.einsum("kji,j->ki", R, [0.0, 0.0, GRAVITY])
    return R, gyro, accel


def test_initial_tilt_from_gravity_with_zero_yaw():
    R_true = pin.rpy.rpyToMatrix(0.3, -0.2, 1.0)
    f = AttitudeFilter(R_true.T @ [0.0, 0.0, GRAVITY])
    assert _tilt_deg(R_true, pin.Quaternion(f.R).coeffs()) < 1e-9
    assert abs(pin.rpy.matrixToRpy(f.R)[2]) < 1e-9   # yaw is not observable: it starts at 0
    np.testing.assert_allclose(f.R @ f.R.T, np.eye(3), atol=1e-12)


def test_the_accelerometer_pulls_a_wrong_tilt_back_with_time_constant_1_over_kp():
    """Started 10° off at rest, the error decays as exp(−KP t): the correction's sign and gain."""
    R_true = pin.rpy.rpyToMatrix(0.1, 0.05, 0.0)
    a = R_true.T @ [0.0, 0.0, GRAVITY]
    f = AttitudeFilter(pin.rpy.rpyToMatrix(0.1 + np.radians(10), 0.05, 0.0).T @ [0.0, 0.0, GRAVITY], ki=0.0)
    dt, errs = 0.002, []
    for _ in range(int(3.0 / dt)):
        errs.append(_tilt_deg(R_true, pin.Quaternion(f.update(dt, np.zeros(3), a)).coeffs()))
    k = int(1.0 / ATTITUDE_KP / dt)
    assert errs[k] / 10.0 == pytest.approx(np.exp(-1.0), rel=0.05)   # one time constant
    assert errs[-1] < 0.6


def test_a_rocking_imu_is_tracked_and_a_gyro_bias_is_learned():
    """Exact readings of a ±11° rocking: the start (tilt from the first 0.1 s of accelerometer
    readings while rocking: 3.5° off) is pulled in and the last 10 s of 40 s stay within 0.05°.
    A horizontal gyro bias b = 0.02·√2 rad/s leaves b / KP = 1.6° without the integral term; with
    it, the slow pole of s² + KP s + KI (1/0.113 s⁻¹ ≈ 9 s) leaves < 0.15° after 30 s (measured 0.104°)."""
    t = np.arange(0.0, 40.0, 0.002)
    R, gyro, accel = _rocking(t)
    last = range(len(t) - 5000, len(t), 10)

    def worst(q: np.ndarray) -> float:
        return max(_tilt_deg(R[k], q[k]) for k in last)
    assert _tilt_deg(R[0], estimate_orientation(t, gyro, accel)[0]) > 1.0   # the start is off
    assert worst(estimate_orientation(t, gyro, accel)) < 0.05
    biased = gyro + [0.02, -0.02, 0.0]
    assert worst(estimate_orientation(t, biased, accel)) < 0.15
    assert worst(estimate_orientation(t, biased, accel, ki=0.0)) > 1.0   # the integral term matters


@pytest.mark.parametrize("accel, match", [
    (np.zeros((10, 3)), "is not gravity"),
    (np.full((10, 3), np.nan), "non-finite"),
])
def test_unusable_readings_are_one_line_errors(accel, match):
    with pytest.raises(EstimationError, match=match):
        estimate_orientation(np.arange(10) * 0.002, np.zeros((10, 3)), accel)
    with pytest.raises(EstimationError, match="expected shape"):
        estimate_orientation(np.arange(10) * 0.002, np.zeros((9, 3)), np.zeros((10, 3)))
