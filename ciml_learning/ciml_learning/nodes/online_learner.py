"""`online_learner`: /model_error/learning_samples → LWPR snapshots + /model_update.

Thin adapter around ciml_learning.learning.online (learning_sample, OnlineLearner) and snapshots
(SnapshotWriter): each learning sample — a filtered state (q, q̇, q̈ → x of eq. 12) and its
measured error of eq. (11)/(14), sent together by error_extractor for valid states, and for some
near contact changes with Γ alone observed — is learned at once with ModelSet.partial_fit_one
(the observed dimensions, ~0.5 ms per sample for all 30).
The extractor sends only what can be learned: most states of a trot are near a contact change,
and a learner niced below every other job, taking every state and error to drop most of them,
got through a third of the stream on a full 2-core machine and learned a fraction of what it
could (results/LIVE_GRAPH.md, fifteenth and sixteenth sessions). Every `snapshot_period`
seconds, if something new was learned, the model set is deep-copied on this thread (the only
stall; its duration is reported on /diagnostics as snapshot_copy_ms) and written by a
worker thread to model_dir/snapshot-NNNNNN (model_dir/latest → newest); once on disk, a
ciml_msgs/ModelUpdate is published (model_dir = the snapshot directory, learner, samples
learned, the whole-model checksum: model.json's `checksum`, which the model server
requires). Snapshots also carry probe_inputs.npy (64 learned inputs, in the manifest) for
the server's bounds check. The subscription queue of `queue_depth` absorbs the copy's stall.

Where the samples go, on /diagnostics: samples_received, samples_lost (gaps in the extractor's
sequence: a full queue while this node was behind, or DDS), then per sample one of
samples_learned, held_back_samples, invalid_samples, paused_* (the gate below).
Rejected inputs are counted on /diagnostics and never learned: samples that do not convert
(non-finite values, wrong joint/foot/error names, wrong sizes: rejected_samples), samples out
of stamp order, and invalid samples (a state not valid: filter warm-up, near a contact change).
At shutdown a last snapshot of unsaved samples is written (not announced).

Learning that cannot poison the loop (ciml_learning.learning.learning_gate, docs/LIVE_GRAPH.md):
valid pairs are learned only while the robot is up (base height, tilt), tracks the
/reference sample of the same stamp (base position, attitude, joints; error_extractor sends it
with the sample: this node reads no topic of the control path, not even /clock, so that its
death cannot stall a control-path writer: docs/LIVE_GRAPH.md, "Transports"), and the measured
error is within the robot's physical bounds (m·g, m·g·leg span, torque limits). Otherwise
learning pauses: /diagnostics WARN "learning paused: <reason>" and the paused_* counters (OK and INFO
for a /reference that never came: nothing a user must act on);
back to OK ("learning …") once the checks have passed for `resume_after` seconds. Without any
/reference (a replayed log) tracking is not checked unless `require_reference`.

A snapshot is announced only if it predicts better than the nominal model on held-back live
samples it was not trained on (ciml_learning.learning.snapshot_gate: one block of stamps in
`hold_back_every` is held back; at least `min_learned` samples learned; per output, its mean
squared error ≤ (1 − `validation_margin`) × the nominal model's on ≥ `min_heldout` held-back
samples); it is announced with its accepted outputs only. Decisions are counted on /diagnostics
(snapshots_accepted, snapshots_refused_too_few_samples, snapshots_refused_not_better_than_nominal;
outputs_served: the newest accepted snapshot's). No learning sample for `input_timeout` seconds
(node clock) after the first: WARN "no samples …" until they come back.
"""
from __future__ import annotations

import dataclasses
import os
import time

from ciml_msgs.msg import LearningSample, ModelUpdate
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.profile import load_profile
from ciml_learning.learning.learning_gate import NO_REFERENCE, GateConfig, LearningGate
from ciml_learning.learning.models import ModelSet
from ciml_learning.learning.online import OnlineLearner, SequenceGaps, learning_sample, warm_up
from ciml_learning.learning.snapshot_gate import HELD_BACK, ValidationConfig
from ciml_learning.learning.snapshots import SnapshotWriter
from ciml_learning.learning.workers import LatestOnlyWorker
from ciml_learning.ros.node_params import ONLINE_LEARNER
from ciml_learning.ros.ros_common import COMMAND_QOS, OK, WARN, Health, declare_schema, run_node
from ciml_learning.ros.ros_common import ERROR as DIAG_ERROR

DEFAULT_MODEL_DIR = os.path.join("~", ".ros", "ciml", "online_model")


class OnlineLearnerNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("online_learner", **kwargs)
        p = declare_schema(self, ONLINE_LEARNER)  # node_params.py: the one schema (all read-only)
        model_dir, self.snapshot_period, keep = p["model_dir"], p["snapshot_period"], p["keep_snapshots"]
        learner, initial, calib = p["learner"], p["initial_model"], p["calibration_samples"]
        depth, record = p["queue_depth"], p["record_stamps"]
        gate = GateConfig(**{f.name: p[f.name] for f in dataclasses.fields(GateConfig)})
        validation = ValidationConfig(block=p["hold_back_block"], every=p["hold_back_every"],
                                      window=p["validation_window"], min_learned=p["min_learned"],
                                      min_heldout=p["min_heldout"], margin=p["validation_margin"]
                                      ) if p["validate_snapshots"] else None
        self.robot = load_profile(p["robot"]).robot()
        self.gate = LearningGate(self.robot, gate)
        if initial:
            ms = ModelSet.load(os.path.expanduser(initial), self.robot)
            self.get_logger().info(f"continuing from {initial} ({int(ms.n_samples_.max())} samples)")
        else:
            ms = ModelSet.for_robot(self.robot, learner)
        self.learner = OnlineLearner(self.robot, ms, calibration_samples=calib, record_stamps=record, gate=self.gate,
                                     validation=validation)
        self.get_logger().info(f"learner code ready in {warm_up(self.robot, ms.learner):.2f} s")
        self._loss_mark: tuple[float, float] = (0, 0)  # (samples received + lost, lost) at the last loss check
        self.lost_samples = SequenceGaps()
        self.writer = SnapshotWriter(model_dir or DEFAULT_MODEL_DIR, keep, validation)
        self.worker = LatestOnlyWorker(self.writer.write, name="snapshot-writer")
        self.snapshot_samples = 0   # samples in the newest snapshot submitted
        self.saved_samples = 0      # samples in the newest snapshot written
        self.learn_times: list[float] = []
        self.health = Health(self)
        self._learning_message = f"learning, snapshots in {self.writer.root}"
        self.health.set(OK, self._learning_message)
        self._paused = False
        self.pub = self.create_publisher(ModelUpdate, topics.MODEL_UPDATE, COMMAND_QOS)
        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(LearningSample, topics.LEARNING_SAMPLES, self.on_sample, qos)
        self.create_timer(self.snapshot_period, self.snapshot)
        self.create_timer(0.05, self.announce)
        self.input_timeout = p["input_timeout"]
        self._last_input: float | None = None  # node clock [s] of the newest learning sample
        self.create_timer(1.0, self.watch_inputs)

    # --- inputs ------------------------------------------------------------------------
    def on_sample(self, msg) -> None:
        self._last_input = self.get_clock().now().nanoseconds * 1e-9
        try:
            sample = learning_sample(self.robot, msg)
        except CimlError as err:
            self.health.count("rejected_samples", f"learning sample rejected: {err}")
            return
        self.lost_samples.add(msg.sequence)
        c = self.health.counts
        c["samples_received"] += 1
        c["samples_lost"] = self.lost_samples.lost
        self._watch_losses(c["samples_received"], c["samples_lost"])
        self._learn(sample)

    def watch_inputs(self) -> None:
        """A learner whose inputs stopped says so (the chain upstream died or stalls)."""
        if self._last_input is None:
            return
        silent = self.get_clock().now().nanoseconds * 1e-9 - self._last_input
        self.health.condition("no_samples", silent > self.input_timeout, WARN,
                              f"no samples: no {topics.LEARNING_SAMPLES} for {silent:.1f} s (no valid state upstream, "
                              "or the chain stopped)")

    def _learn(self, sample) -> None:
        t0 = time.perf_counter()
        reason = self.learner.learn(*sample)
        dt = time.perf_counter() - t0
        self._sync_gate()
        if reason is not None:
            if reason.startswith("paused_"):
                self.health.counts[reason] = self.learner.counts[reason]
            elif reason not in ("invalid_samples", HELD_BACK):  # expected (contact changes, validation): counted
                self.health.count(reason, f"sample at stamp {sample[0]} not learned: {reason}")
            else:
                self.health.count(reason)
            return
        self.learn_times.append(dt)
        c = self.health.counts
        c["samples_learned"] = self.learner.n_learned
        if len(self.learn_times) >= 250:
            c["learn_us_mean"] = int(1e6 * sum(self.learn_times) / len(self.learn_times))
            c["learn_us_max"] = int(1e6 * max(self.learn_times))
            self.learn_times.clear()

    def _sync_gate(self) -> None:
        """/diagnostics follows the gate: WARN with the reason while paused, OK when learning. A pause
        for a /reference that never came (the extractor's wait for it timed out) is nothing
        the user must act on: OK and INFO, counted (paused_no_reference); `starved` warns on losses."""
        if self.gate.paused and (not self._paused or self.health.mode_message != self._pause_text()):
            waiting = self.gate.key == NO_REFERENCE
            self.health.set(OK if waiting else WARN, self._pause_text())
            if not self._paused and waiting:  # rclpy: one severity per call site
                self.get_logger().info(self._pause_text())
            elif not self._paused:
                self.get_logger().warning(self._pause_text())
        elif not self.gate.paused and self._paused:
            self.health.set(OK, self._learning_message)
            self.health.counts["resumed"] = self.gate.counts["resumed"]
            self.get_logger().info("learning resumed")
        self._paused = self.gate.paused

    def _pause_text(self) -> str:
        return f"learning paused: {self.gate.reason}"

    LOST_WARN = 0.2
    """WARN when more than this share of the learning samples was lost over the last ~250: the
    learner (niced below every other job) does not get the CPU to keep up, and learns little."""

    def _watch_losses(self, received: float, lost: float) -> None:
        seen = received + lost
        if seen - self._loss_mark[0] < 250:
            return
        share = (lost - self._loss_mark[1]) / (seen - self._loss_mark[0])
        self.health.condition("starved", share > self.LOST_WARN, WARN,
                              f"learning starved: {100 * share:.0f} % of the learning samples lost (the learner falls "
                              "behind: the machine is too loaded)")
        self._loss_mark = (seen, lost)

    # --- snapshots ---------------------------------------------------------------------
    def snapshot(self) -> None:
        if self.learner.n_learned <= self.snapshot_samples:
            return
        if self.worker.busy:
            self.health.count("snapshots_deferred", "previous snapshot still being written")
            return
        snap = self.learner.snapshot()
        self.snapshot_samples = snap.samples
        self.health.counts["snapshot_copy_ms"] = int(round(1e3 * snap.copy_seconds))
        self.worker.submit(snap)

    def announce(self) -> None:
        for result in self.worker.drain():
            if result.error is not None:
                self.health.count("snapshot_failures")
                # ERROR until a snapshot is written again (then it clears)
                self.health.condition("snapshot_failed", True, DIAG_ERROR, f"snapshot not written: {result.error}")
                self.get_logger().error(f"snapshot not written: {result.error}")
                self.snapshot_samples = self.saved_samples  # retry at the next period
                continue
            saved = result.value
            self.health.condition("snapshot_failed", False)
            if saved.validation is not None:
                self.health.counts[saved.validation.decision] += 1
                if not saved.validation.served:
                    self.snapshot_samples = self.saved_samples  # not written: the next period tries again
                    self.get_logger().info(f"snapshot not served ({saved.validation.decision}: "
                                           f"{saved.validation.summary()})")
                    continue
                self.health.counts["outputs_served"] = int(saved.validation.accepted.sum())
            self.saved_samples = max(self.saved_samples, saved.samples)
            msg = ModelUpdate(header=cv.header_msg(self.get_clock().now().nanoseconds), model_dir=saved.model_dir,
                              learner=saved.learner, samples=saved.samples, checksum=saved.checksum)
            self.pub.publish(msg)
            self.health.counts["snapshots_written"] += 1
            self.health.counts["snapshot_write_ms"] = int(round(1e3 * saved.write_seconds))
            self.get_logger().info(f"snapshot {saved.model_dir} ({saved.samples} samples, "
                                   f"write {1e3 * saved.write_seconds:.0f} ms)")

    def destroy_node(self) -> None:
        """Write the samples learned since the last snapshot before exiting (not announced)."""
        try:
            if self.learner.n_learned > self.snapshot_samples:
                # written whole, without the gate: it is not announced, only kept to continue from
                snap = dataclasses.replace(self.learner.snapshot(), heldout=None)
                self.snapshot_samples = snap.samples
                self.worker.submit(snap)  # replaces a snapshot that has not started yet
            self.worker.close()           # finishes the running and the pending one
        finally:
            super().destroy_node()


def main(args=None) -> None:
    run_node(OnlineLearnerNode, args)
