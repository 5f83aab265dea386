"""`error_extractor`: /filtered_state → /model_error/measured (eq. 11 and 14) + /model_error/learning_samples.

Thin adapter around ciml_learning.core.extraction.extract; rejected inputs are counted on
/diagnostics and never produce an output. Every extracted error goes to /model_error/measured
(for plots and recording); each one with a usable part also goes, with the state it came from, to
/model_error/learning_samples as one ciml_msgs/LearningSample with a running `sequence`: the
rigid-body error observed where the state is `valid` (not near a contact change, no bridged gap),
the actuation error where it is `effort_valid` (no bridged gap: Γ = τ − u does not see the
contacts, filters.contact_change_mask) — of the states with only Γ usable, every
`effort_sample_every`-th (the learner's CPU, not the data, bounds how many it can take). The
online learner then takes only what it can learn and counts a sequence gap as lost samples.
States are extracted in batches, every `batch_period` of wall-clock time: extract is vectorised,
and one state alone costs ~4× its share of a batch of 5 (results/LIVE_GRAPH.md, third session),
which on a 2-core machine is the difference between keeping up at 250 Hz and not. The outputs are the same, in order,
at most `batch_period` later.

Each learning sample carries the /reference sample nearest its stamp (within `max_reference_age`;
pairing.ReferenceHistory), for the learner's tracking check; a sample waits for the
reference stream to pass its stamp (learning_gate.AwaitReference, at most `max_pair_age` of
stamps). So the online learner reads no topic of the control path: a process killed while a
control-path node writes to it can stall that node (docs/LIVE_GRAPH.md, "Transports"), and the
learner is the process most likely to die.
"""
from __future__ import annotations

import numpy as np
from ciml_msgs.msg import LearningSample, ModelError, RobotReference, RobotState
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.serialization import deserialize_message
from rclpy.timer import Timer

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.extraction import extract
from ciml_learning.core.pairing import ReferenceHistory
from ciml_learning.core.profile import load_profile
from ciml_learning.learning.learning_gate import AwaitReference
from ciml_learning.ros.node_params import ERROR_EXTRACTOR
from ciml_learning.ros.ros_common import STREAM_QOS, Health, declare_schema, run_node


class ErrorExtractorNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("error_extractor", **kwargs)
        p = declare_schema(self, ERROR_EXTRACTOR, self._apply_parameters)  # node_params.py: the one schema
        self.gamma = p["gamma"]
        self.robot = load_profile(p["robot"]).robot()
        self.health = Health(self)
        self.pending: list[tuple] = []  # (state msg, stamp ns, q, v, q̈, τ, τ̇, u, contacts, valid, effort_valid)
        self.sequence = 0               # learning samples published
        self.effort_sample_every = p["effort_sample_every"]
        self.effort_only = 0            # states with only Γ usable, seen (effort_sample_every picks from them)
        self.references = ReferenceHistory(int(p["max_reference_age"] * 1e9))
        self.waiting = AwaitReference(self.references.max_age_ns, int(p["max_pair_age"] * 1e9))
        self.timer: Timer | None = None
        self._set_batch_period(p["batch_period"])
        self.pub = self.create_publisher(ModelError, topics.MODEL_ERROR_MEASURED, STREAM_QOS)
        self.sample_pub = self.create_publisher(LearningSample, topics.LEARNING_SAMPLES, STREAM_QOS)
        self.create_subscription(RobotState, topics.FILTERED_STATE, self.on_state, STREAM_QOS)
        # kept serialized: only the references sent with a learning sample are decoded (decoding one costs
        # ~80 µs, at 250 Hz a few % of a core in the learning container, the chain's scarcest CPU)
        self.create_subscription(RobotReference, topics.REFERENCE, self.on_reference, STREAM_QOS, raw=True)

    def _apply_parameters(self, changes: dict) -> str | None:
        self.gamma = changes.get("gamma", self.gamma)  # used by the next extraction
        if "batch_period" in changes:
            self._set_batch_period(changes["batch_period"])
        return None

    def _set_batch_period(self, period: float) -> None:
        if self.timer is not None:
            self.destroy_timer(self.timer)
            self.timer = None
        self.batch_period = period
        if period > 0:  # wall clock: batching is about CPU time, and must not stop with /clock
            self.timer = self.create_timer(period, self.flush, clock=Clock(clock_type=ClockType.STEADY_TIME))
        self.flush()

    def on_state(self, msg) -> None:
        try:
            arrays = cv.robot_state_arrays(self.robot, msg)
        except CimlError as err:
            self.health.count("rejected_states", f"filtered_state rejected: {err}")
            return
        self.pending.append((msg, cv.stamp_to_ns(msg.header.stamp), *arrays))
        if self.batch_period <= 0:
            self.flush()

    def on_reference(self, data: bytes) -> None:
        try:
            self.references.add(cv.serialized_stamp_ns(data), data)
        except CimlError as err:
            self.health.count("rejected_references", f"/reference rejected: {err}")

    def flush(self) -> None:
        """Extract and publish every pending state, in arrival order; send the learning samples
        whose reference is in."""
        self._send_samples()
        if not self.pending:
            return
        batch, self.pending = self.pending, []
        states, stamps, q, v, a, tau, tau_dot, u, contacts, valid, effort_valid = (list(x) for x in zip(*batch))
        res = extract(self.robot, np.array(q), np.array(v), np.array(a), np.array(tau), np.array(u),
                      np.array(contacts), gamma=self.gamma, tau_dot=np.array(tau_dot))
        for i, ns in enumerate(stamps):
            if not res.valid[i]:
                self.health.count("non_finite_extraction", "extraction produced a non-finite value")
                continue
            observed_act = np.full(self.robot.n_joints, bool(effort_valid[i]))
            error = cv.model_error_msg(self.robot, ns, "measured", res.rbd_error[i], res.rbd_observed[i] & valid[i],
                                       res.actuation_error[i], observed_act)
            self.pub.publish(error)
            if valid[i] or (effort_valid[i] and self._take_effort_only()):
                self.waiting.push(ns, LearningSample(header=error.header, state=states[i], error=error))
        self.health.counts["batch_max"] = max(self.health.counts["batch_max"], len(batch))
        self._send_samples()

    def _take_effort_only(self) -> bool:
        self.effort_only += 1
        return self.effort_sample_every > 0 and self.effort_only % self.effort_sample_every == 0

    def _send_samples(self) -> None:
        for ns, sample in self.waiting.ready(self.references.newest):
            self.sequence += 1
            sample.sequence = self.sequence
            reference = self.references.at(ns)
            sample.reference = RobotReference() if reference is None else deserialize_message(reference, RobotReference)
            sample.references_heard = self.references.heard
            self.sample_pub.publish(sample)


def main(args=None) -> None:
    run_node(ErrorExtractorNode, args)
