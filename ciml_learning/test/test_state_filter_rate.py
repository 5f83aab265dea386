"""state_filter designs its filters for the measured /joint_states rate (rate parameter 0,
the default) and then equals the offline pipeline, which measures the whole log's rate."""
import numpy as np
import pytest


@pytest.mark.ros
def test_node_measures_the_rate_and_matches_offline():
    import rclpy

    from ciml_learning.core.filters import filter_state_log
    from ciml_learning.nodes.state_filter import RATE_SAMPLES, StateFilterNode

    rclpy.init()
    try:
        node = StateFilterNode()
        sent = []
        node.pub = type("Pub", (), {"publish": lambda self, m: sent.append(m)})()
        robot = node.robot
        fs, n = 448.0, 300
        t = 1.0 + np.arange(n) / fs
        qj = robot.standing_joints[None, :] + 0.1 * np.sin(2 * np.pi * 1.3 * t[:, None])
        qdj = 0.1 * 2 * np.pi * 1.3 * np.cos(2 * np.pi * 1.3 * t[:, None])
        tau = 10.0 * np.sin(2 * np.pi * 0.9 * t[:, None]) + np.arange(12)
        pos, quat, twist = np.array([0, 0, 0.6]), np.array([0, 0, 0, 1.0]), np.zeros(6)
        contacts = np.ones(4, bool)
        for k in range(n):  # u = τ[0], constant
            node.process(int(round(t[k] * 1e9)), np.r_[pos, quat, qj[k]], np.r_[twist, qdj[k]], tau[k], tau[0],
                         contacts)
        assert node.filter is not None and node.filter.fs == pytest.approx(fs, rel=1e-6)
        assert len(sent) == n - 2 * node.filter.delay  # the samples held while measuring are not lost
        q = np.hstack([np.tile(pos, (n, 1)), np.tile(quat, (n, 1)), qj])
        v = np.hstack([np.zeros((n, 6)), qdj])
        off = filter_state_log(t, q, v, tau, np.tile(tau[0], (n, 1)), np.ones((n, 4), bool))
        assert off.rate_hz == pytest.approx(fs, rel=1e-6)
        for msg in sent[::25]:
            k = int(np.argmin(np.abs(t - (msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9))))
            np.testing.assert_allclose(msg.acceleration, off.a[k, 6:], atol=1e-6)
            np.testing.assert_allclose(msg.effort_rate, off.tau_dot[k], atol=1e-6)
        assert RATE_SAMPLES < n
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
