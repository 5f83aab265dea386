"""`error_extractor`: /filtered_state → /model_error/measured (eq. 11 and 14).

Thin adapter around ciml_learning.extraction.extract; rejected inputs are counted on
/diagnostics and never produce an output.
"""
from __future__ import annotations

import numpy as np
from ciml_msgs.msg import ModelError, RobotState
from rclpy.node import Node

from .. import conversions as cv
from .. import topics
from ..errors import CimlError
from ..extraction import extract
from ..node_params import ERROR_EXTRACTOR
from ..robot import load_robot
from ..ros_common import COMMAND_QOS, Health, declare_schema, run_node


class ErrorExtractorNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("error_extractor", **kwargs)
        p = declare_schema(self, ERROR_EXTRACTOR, self._apply_parameters)  # node_params.py: the one schema
        self.gamma, urdf = p["gamma"], p["urdf"]
        self.robot = load_robot(urdf or None)
        self.health = Health(self)
        self.pub = self.create_publisher(ModelError, topics.MODEL_ERROR_MEASURED, COMMAND_QOS)
        self.create_subscription(RobotState, topics.FILTERED_STATE, self.on_state, COMMAND_QOS)

    def _apply_parameters(self, changes: dict) -> str | None:
        self.gamma = changes.get("gamma", self.gamma)  # used by the next extraction
        return None

    def on_state(self, msg) -> None:
        try:
            q, v, a, tau, tau_dot, u, contacts, valid = cv.robot_state_arrays(self.robot, msg)
        except CimlError as err:
            self.health.count("rejected_states", f"filtered_state rejected: {err}")
            return
        res = extract(self.robot, q[None], v[None], a[None], tau[None], u[None], contacts[None], gamma=self.gamma,
                      tau_dot=tau_dot[None])
        if not res.valid[0]:
            self.health.count("non_finite_extraction", "extraction produced a non-finite value")
            return
        ns = cv.stamp_to_ns(msg.header.stamp)
        observed_act = np.full(self.robot.n_joints, bool(valid))
        self.pub.publish(cv.model_error_msg(self.robot, ns, "measured", res.rbd_error[0],
                                            res.rbd_observed[0] & valid, res.actuation_error[0], observed_act))


def main(args=None) -> None:
    run_node(ErrorExtractorNode, args)
