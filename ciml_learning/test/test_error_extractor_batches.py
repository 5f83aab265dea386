"""error_extractor extracts in batches (batch_period) and publishes exactly what it publishes
state by state (batch_period 0): the same messages, in the same order."""
import numpy as np
import pytest


@pytest.mark.ros
def test_batches_publish_the_same_errors_in_order():
    import rclpy
    from rclpy.parameter import Parameter

    from ciml_learning.core import conversions as cv
    from ciml_learning.nodes.error_extractor import ErrorExtractorNode

    rclpy.init()
    try:
        out = {}
        for period in (0.0, 0.02):
            node = ErrorExtractorNode(parameter_overrides=[Parameter("batch_period", value=period)])
            sent = []
            node.pub = type("Pub", (), {"publish": lambda self, m, sent=sent: sent.append(m)})()
            robot, rng = node.robot, np.random.default_rng(0)
            q0 = robot.neutral_configuration()
            q0[7:] = robot.standing_joints
            for k in range(12):
                q = q0.copy()
                q[7:] += 0.05 * rng.standard_normal(robot.n_joints)
                v, a = rng.standard_normal(robot.nv), rng.standard_normal(robot.nv)
                tau, u = 10 * rng.standard_normal(robot.n_joints), 10 * rng.standard_normal(robot.n_joints)
                contacts = np.array([k % 2 == 0, True, True, k % 3 == 0])
                node.on_state(cv.robot_state_msg(robot, 10**9 + k * 4_000_000, q, v, a, tau, np.zeros(robot.n_joints),
                                                 u, contacts, k != 5))
            if period > 0:
                assert sent == []  # waiting for the batch timer
                node.flush()
            out[period] = sent
            node.destroy_node()
        once, batched = out[0.0], out[0.02]
        assert len(once) == len(batched) == 12
        for a, b in zip(once, batched):
            assert a.header.stamp == b.header.stamp and list(a.rbd_observed) == list(b.rbd_observed)
            np.testing.assert_allclose(a.rbd_error, b.rbd_error, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(a.actuation_error, b.actuation_error, rtol=1e-9, atol=1e-9)
        assert not any(batched[5].actuation_observed) and all(batched[4].actuation_observed)
    finally:
        rclpy.try_shutdown()
