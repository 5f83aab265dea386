"""`reference_generator`: publishes the full-body reference of a motion on /reference.

Thin adapter around ciml_control.references: at `rate` Hz it samples the motion at the
time elapsed since the motion started (node clock: simulation time with use_sim_time) plus
`lookahead`, and publishes ciml_msgs/RobotReference (qᵈ, q̇ᵈ, q̈ᵈ and the contact schedule)
stamped with that instant, ahead of the clock. Why ahead: stamped now, the reference of an
instant arrives after the robot's sample of that instant (both follow the same clock tick), so
the controller tracked the reference of one period before and mostly used a model-error
prediction of two periods before; on go1 a learned ε one 4 ms period late costs 14 % more
feedback effort than ε on time (headless). Why two periods (8 ms at 250 Hz): with one, the model
server (another process) still answered 12–70 % of the references after the sample that needed
them; with two, none (live, lockstep; results/LIVE_GRAPH.md, twenty-fifth session).
The motion starts `start_delay` seconds after the robot comes under torque control (the
first MODE_TORQUE /torque_command), so it starts from the standing pose whatever the
order in which the nodes start and whoever subscribes first (a dashboard, a recorder or
the learner must not start it while the robot driver still holds the robot); until then
the node publishes the motion's first sample, the standing pose.

/torque_command is taken serialized and read only until the motion has its start: the
subscription is kept, not destroyed, because destroying a DDS reader cost the node ~110 ms of
CPU in one callback, at the moment the controller takes over (measured in the live graph,
one process per node): /reference then went stale and the controller damped the robot.
"""
from __future__ import annotations

import sys

from ciml_msgs.msg import RobotReference, TorqueCommand
from rclpy.node import Node
from rclpy.serialization import deserialize_message

from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.profile import load_profile
from ciml_learning.ros.ros_common import COMMAND_QOS, ERROR, Health, declare_schema, run_node

from ..conversions import reference_msg
from ..node_params import REFERENCE_GENERATOR
from ..references import make_reference, standing_configuration


class ReferenceGeneratorNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("reference_generator", **kwargs)
        p = declare_schema(self, REFERENCE_GENERATOR, self._apply_parameters)  # node_params.py: the one schema
        motion, rate, foot_height = p["motion"], p["rate"], p["foot_height"]
        self.robot = load_profile(p["robot"]).robot()
        self.reference = make_reference(self.robot, motion, standing_configuration(self.robot, foot_height))
        self.health = Health(self)
        self.pub = self.create_publisher(RobotReference, topics.REFERENCE, COMMAND_QOS)
        self.start_delay_ns = int(p["start_delay"] * 1e9)
        self.lookahead_ns = int(round(p["lookahead"] * 1e9))
        self.start_ns: int | None = None
        if p["start_on_command"]:
            self.create_subscription(TorqueCommand, topics.TORQUE_COMMAND, self.on_command, COMMAND_QOS, raw=True)
        else:
            self.start_ns = self.get_clock().now().nanoseconds + self.start_delay_ns
        self.timer = self.create_timer(1.0 / rate, self.tick)
        self.get_logger().info(f"publishing {motion} on {topics.REFERENCE} at {rate:.0f} Hz")

    def _apply_parameters(self, changes: dict) -> str | None:
        """`rate` and `lookahead` at run time: the publish timer is replaced (the motion's clock goes on)."""
        if "lookahead" in changes:
            self.lookahead_ns = int(round(changes["lookahead"] * 1e9))
        if "rate" in changes:
            self.destroy_timer(self.timer)
            self.timer = self.create_timer(1.0 / changes["rate"], self.tick)
            self.get_logger().info(f"publishing at {changes['rate']:g} Hz")
        return None

    def on_command(self, raw: bytes) -> None:
        if self.start_ns is not None:  # started: a take, no conversion
            return
        if deserialize_message(raw, TorqueCommand).mode == TorqueCommand.MODE_TORQUE:
            self.start_ns = self.get_clock().now().nanoseconds + self.start_delay_ns
            self.get_logger().info(f"the robot is under torque control: the motion starts in "
                                   f"{self.start_delay_ns * 1e-9:g} s")

    def tick(self) -> None:
        at = self.get_clock().now().nanoseconds + self.lookahead_ns
        try:
            point = self.reference.sample(0.0 if self.start_ns is None else max(0.0, (at - self.start_ns) * 1e-9))
        except CimlError as err:  # e.g. an unreachable foot target: publish nothing
            self.health.count("reference_errors", str(err), level=ERROR)  # ERROR while it lasts
            return
        self.pub.publish(reference_msg(self.robot, at, point))
        self.health.counts["published"] += 1


def main(args=None) -> None:
    try:
        run_node(ReferenceGeneratorNode, args)
    except CimlError as err:
        print(f"reference_generator: {err}", file=sys.stderr)
        sys.exit(1)
