"""`state_filter`: a robot's own sensor topics → /filtered_state (paper §III-C, online filter).

Thin adapter around ciml_learning.logs.live_inputs.LiveInputs and filters.OnlineStateFilter. It
subscribes to the topics of the `robot` profile's input map (docs/ROBOT_PROFILE.md: CIML's own
/joint_states, /base_state, /contact_state, /torque_command for hyq; a Unitree layout's joint
states with foot entries, IMU, foot-force array and effort or LowCmd command for go1) and hands
every message to LiveInputs, which reads it with load_log's readers and pairs each joint sample by
ciml_learning.core.pairing's rule, as a log is read offline. Rejected messages and samples are counted
on /diagnostics; a topic that stays silent while others speak, or every topic once any spoke, is
a WARN there (live_inputs.input_silence). With
`inputs: ciml` it reads CIML's own topics for any robot instead (the simulator bridge publishes
those; the shipped launch file sets it). Output is aligned to the filter's delay (≈ 60 ms at any rate).

The filters are designed for the rate of the joint states: the `rate` parameter, or (0, the
default) the rate measured from the first RATE_SAMPLES stamps (median period, as the
offline pipeline measures a whole log); those first samples are held and filtered once
the rate is known, so nothing is lost and online still equals offline.
"""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np
from ciml_msgs.msg import RobotState
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.filters import OnlineStateFilter
from ciml_learning.core.profile import TORQUE_COMMAND, load_profile
from ciml_learning.core.stamps import measure_rate
from ciml_learning.logs.live_inputs import LiveInputs, input_silence
from ciml_learning.ros.node_params import STATE_FILTER
from ciml_learning.ros.replay import message_class
from ciml_learning.ros.ros_common import (
    OK,
    SENSOR_STREAM_QOS,
    STREAM_QOS,
    Health,
    PublishPeriods,
    declare_schema,
    run_node,
)

RATE_SAMPLES = 32
"""Joint samples whose stamps set the filter's rate when the `rate` parameter is 0."""


class StateFilterNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("state_filter", **kwargs)
        p = declare_schema(self, STATE_FILTER, self._apply_parameters)  # node_params.py: the one schema
        fs, self.max_age = p["rate"], p["max_age"]
        profile = load_profile(p["robot"])
        self.robot = profile.robot()
        if p["inputs"] == "ciml":  # the robot on CIML's own topics: the shipped hyq profile's input map
            profile = dataclasses.replace(profile, inputs=load_profile("hyq").inputs)
        if 0.0 < fs < 50.0:
            raise CimlError(f"rate {fs} Hz is too low for the 10 Hz low-pass (20 Hz stopband); give ≥ 50 Hz or 0")
        self.filter = OnlineStateFilter(fs) if fs > 0 else None
        self.periods: PublishPeriods | None = None  # /filtered_state as published, once the rate is known
        self._rate_samples: list = []  # held while the rate is measured
        self.health = Health(self)
        self.inputs = LiveInputs(self.robot, profile, self.max_age, self._reject)
        self.pub = self.create_publisher(RobotState, topics.FILTERED_STATE, STREAM_QOS)
        self.last_heard: dict[str, float | None] = {}
        for topic, msgtype, roles in self.inputs.subscriptions():
            cls = message_class(msgtype)  # a type not installed here: one line at start (BagError)
            # sensors best effort (matches any driver); CIML's own controller's commands reliable, as published
            qos = STREAM_QOS if msgtype == TORQUE_COMMAND else SENSOR_STREAM_QOS
            # rclpy passes the message info to a two-argument callback (its type hint knows one argument)
            self.create_subscription(cls, topic, self._receiver(topic), qos)  # type: ignore[arg-type]
            self.last_heard[topic] = None
            self.get_logger().info(f"{'/'.join(roles)}: {topic} ({msgtype})")
        self.started = time.monotonic()
        self.create_timer(1.0, self.check_silent, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _apply_parameters(self, changes: dict) -> str | None:
        self.max_age = changes.get("max_age", self.max_age)
        self.inputs.max_age_s = self.max_age  # used by the next pairing
        return None

    def _reject(self, event: str, reason: str | None) -> None:
        self.health.count(event, reason)

    def _receiver(self, topic: str) -> Callable[[Any, Any], None]:
        return lambda msg, info: self.on_message(topic, msg, info)

    def on_message(self, topic: str, msg, info) -> None:
        # the publish time places headerless messages among the joint states (live_inputs)
        self.last_heard[topic] = time.monotonic()
        for sample in self.inputs.add(topic, msg, info["source_timestamp"]):
            self.process(*sample)

    def check_silent(self) -> None:
        """The inputs' silence warnings (wall clock); OK "waiting" before the first message."""
        for name, active, message in input_silence(self.last_heard, self.started, time.monotonic()):
            self.health.condition(name, active, message=message)
        waiting = all(t is None for t in self.last_heard.values())
        self.health.condition("waiting", waiting, OK, f"waiting for {', '.join(self.last_heard)}")

    def process(self, stamp: int, q: np.ndarray, v: np.ndarray, tau: np.ndarray, u: np.ndarray,
                contacts: np.ndarray) -> None:
        """Filter one paired sample stamped `stamp` [ns] (LiveInputs: Pinocchio q, v; τ; the
        command's torque u at that sample; contact flags)."""
        if self.filter is None:
            self._rate_samples.append((stamp * 1e-9, q, v, tau, u, contacts))
            if len(self._rate_samples) < RATE_SAMPLES:
                return
            fs = measure_rate(np.array([x[0] for x in self._rate_samples])).rate_hz
            if not 50.0 <= fs <= 2000.0:
                self.health.count("rate_out_of_range", f"measured /joint_states rate {fs:.1f} Hz is outside 50–2000 Hz")
                self._rate_samples.clear()
                return
            self.get_logger().info(f"joint-state rate measured from the stamps: {fs:.2f} Hz")
            self.filter = OnlineStateFilter(fs)
            held, self._rate_samples = self._rate_samples, []
        else:
            held = [(stamp * 1e-9, q, v, tau, u, contacts)]
        for sample in held:
            self._filter(*sample)

    def _filter(self, t: float, q, v, tau, u, contacts) -> None:
        assert self.filter is not None  # process() makes it before passing any sample on
        try:
            ready = self.filter.push(t, q, v, tau, u, contacts)
        except ValueError as err:
            self.health.count("rejected_samples", str(err))
            return
        if self.periods is None:
            self.periods = PublishPeriods(self.health, "filtered_state", self.filter.fs)
        # joint samples lost upstream: bridged by interpolation, or a restarted warm-up
        self.health.counts["joint_samples_filled"] = self.filter.filled
        self.health.counts["filter_restarts"] = self.filter.restarts
        # the share the learning chain can use: states away from contact changes and bridged gaps
        # (the rigid-body error), states away from bridged gaps (the actuation error)
        for key in ("valid", "contact_change", "bridged_gap_window", "effort_valid"):
            self.health.counts[f"states_{key}"] = self.filter.counts[key]
        for out in ready:
            ns = int(round(out.t * 1e9))
            self.pub.publish(cv.robot_state_msg(self.robot, ns, out.q, out.v, out.a, out.tau, out.tau_dot, out.u,
                                                out.contacts, out.valid, out.effort_valid))
            self.periods.mark()


def main(args=None) -> None:
    run_node(StateFilterNode, args)
