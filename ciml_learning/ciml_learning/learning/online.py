"""Online learning without ROS: the algorithms of the `online_learner` node
(docs/ARCHITECTURE.md §3), testable without rclpy (paper §III-D, LWPR learning at 250 Hz).

- learning_sample decodes what error_extractor sends the learner: a valid filtered state
  (q, q̇, q̈ of eq. 12, τ, τ̇) with its measured error (Φ̃' of eq. 11, Γ of eq. 14) in one
  message (/model_error/learning_samples), so no pairing of two streams is needed;
  SequenceGaps counts the samples lost on the way. The extractor attaches the /reference of
  the sample's instant (pairing.ReferenceHistory, learning_gate.AwaitReference).
- OnlineLearner feeds each valid pair, in increasing stamp order, to
  ModelSet.partial_fit_one with x = learning_inputs(q, q̇, q̈, τ, τ̇) and the measured Φ̃'
  turned into the set's targets Φ̃ = J'ᵀΦ̃' and leg coupling C with the contact-invariant
  basis at q (projection.generalized_rbd_error, leg_coupling — as the extraction does). Optionally the
  first `calibration_samples` valid pairs are buffered to calibrate the set's input and
  output scaling (ModelSet.calibrate), then learned in order. It can record the stamps
  it learned, in order: offline ModelSet.partial_fit on the same samples in the same
  order reproduces the online model (test/test_online_learning.py). Its snapshots are
  written by snapshots.SnapshotWriter on a workers.LatestOnlyWorker thread and served by
  serving.load_served_model.
"""
from __future__ import annotations

import copy
import time
from collections import Counter
from dataclasses import dataclass

import numpy as np

from ciml_learning.core.conversions import model_error_arrays, robot_reference_arrays, robot_state_arrays, stamp_to_ns
from ciml_learning.core.dynamics import RigidBodyDynamics
from ciml_learning.core.extraction import learning_inputs
from ciml_learning.core.physical_bounds import N_BASE
from ciml_learning.core.projection import contact_invariant_basis, generalized_rbd_error, leg_coupling
from ciml_learning.core.robot import RobotDescription
from ciml_learning.learning.learners import learner_class
from ciml_learning.learning.models import ModelSet, ModelSetError
from ciml_learning.learning.serving import probe_inputs
from ciml_learning.learning.snapshot_gate import HELD_BACK, HeldBackWindow, ValidationConfig
from ciml_learning.learning.snapshots import Snapshot

N_PROBES = 64
"""Learned inputs kept (reservoir sampling) for a snapshot's probe file (snapshots.PROBE_FILE)."""


# ---------------------------------------------------------------------- messages → arrays
@dataclass
class StateSample:
    """The part of a filtered state the learner uses (Pinocchio q, v, q̈; τ, τ̇; its `valid` and
    `effort_valid` flags: ciml_msgs/RobotState)."""

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    tau: np.ndarray
    tau_dot: np.ndarray
    valid: bool
    effort_valid: bool


@dataclass
class ErrorSample:
    """A measured model error in the robot's orders: Φ̃' (18) + mask, Γ (n_j) + mask."""

    rbd_error: np.ndarray
    rbd_observed: np.ndarray
    actuation_error: np.ndarray
    actuation_observed: np.ndarray


def learning_sample(robot: RobotDescription, msg) -> tuple[int, StateSample, ErrorSample, np.ndarray | None, bool]:
    """A ciml_msgs/LearningSample as (stamp [ns], StateSample, ErrorSample, qᵈ of the reference of
    its instant or None, whether the extractor heard any reference) in the robot's orders
    (joint_names, rbd_error_names): the conversions decode and check every part (ConversionError)."""
    q, v, a, tau, tau_dot, _u, _contacts, valid, effort_valid = robot_state_arrays(robot, msg.state)
    e = model_error_arrays(robot, msg.error)
    q_ref = robot_reference_arrays(robot, msg.reference)[0] if len(msg.reference.joint_names) else None
    return (stamp_to_ns(msg.header.stamp), StateSample(q, v, a, tau, tau_dot, valid, effort_valid),
            ErrorSample(e.rbd_error, e.rbd_observed, e.actuation_error, e.actuation_observed), q_ref,
            msg.references_heard > 0)


# ---------------------------------------------------------------------- pairing by stamp
class SequenceGaps:
    """Samples lost between a publisher's running `sequence` numbers (LearningSample): a step of k
    lost k − 1. Counts what a full subscription queue overwrote or DDS dropped — losses it does not
    report. A sequence that goes back is a restarted publisher: counting starts over."""

    def __init__(self) -> None:
        self.last: int | None = None
        self.lost = 0

    def add(self, sequence: int) -> None:
        sequence = int(sequence)
        if self.last is not None and sequence > self.last:
            self.lost += sequence - self.last - 1
        self.last = sequence


# ---------------------------------------------------------------------- learning
class OnlineLearner:
    """ModelSet.partial_fit_one on valid (state, error) pairs in increasing stamp order.

    learn() returns None when the pair was learned (or buffered for calibration), else
    the name of the rejection, which is also counted in `counts`:
    - "out_of_order_pairs": stamp not after the last learned one (learning order matters);
    - "invalid_samples": nothing in the error is observed where the state is usable (Φ̃' where
      it is `valid`: not near a contact change or a bridged gap; Γ where it is `effort_valid`);
    - "non_finite_inputs": x is not finite (cannot happen after the conversions' checks);
    - with a `gate` (learning_gate.LearningGate): its pause reasons (fall, tracking error,
      target beyond physical bounds, no reference, recovering);
    - with `validation` (snapshot_gate.ValidationConfig): "held_back_samples", a sample of a
      held-back block, kept in `heldout` (not learned) to validate snapshots on.
    A uniform sample of the learned inputs (N_PROBES, reservoir sampling) goes with every
    snapshot, for the model server's bounds check.
    Γ entries whose actuation_observed flag is false are not learned (passed as NaN,
    which partial_fit_one skips per dimension); Φ̃' entries follow rbd_observed.
    """

    def __init__(self, robot: RobotDescription, model_set: ModelSet, calibration_samples: int = 0,
                 record_stamps: bool = False, gate=None, validation: ValidationConfig | None = None) -> None:
        if calibration_samples < 0:
            raise ValueError("calibration_samples must be >= 0")
        if not learner_class(model_set.learner).supports_partial_fit:
            raise ModelSetError(f"learner {model_set.learner!r} cannot learn online (no partial_fit); use 'lwpr'")
        model_set.check_robot(robot)
        self.robot = robot
        self.model_set = model_set
        self._dyn = RigidBodyDynamics(robot)
        self.calibration_samples = 0 if model_set.is_fitted() else int(calibration_samples)
        self.record_stamps = bool(record_stamps)
        self.counts: Counter[str] = Counter()
        self.n_learned = 0
        self.last_stamp: int | None = None
        self._buffer: list[tuple[int, tuple[np.ndarray, ...]]] = []
        self._stamps = np.empty(1024 if record_stamps else 0, dtype=np.int64)
        self.gate = gate
        self.validation = validation
        self.heldout = (HeldBackWindow(validation.window, len(model_set.input_names), model_set.n_rbd,
                                       model_set.n_actuation) if validation is not None else None)
        self._probes: list[np.ndarray] = []
        self._probe_rng = np.random.default_rng(0)
        self._probe_seen = 0

    @property
    def calibrating(self) -> bool:
        return self.calibration_samples > 0

    @property
    def learned_stamps(self) -> np.ndarray:
        """Stamps of the learned samples in learning order (empty without record_stamps)."""
        return self._stamps[: self.n_learned if self.record_stamps else 0]

    def _reject(self, reason: str) -> str:
        self.counts[reason] += 1
        return reason

    def learn(self, stamp: int, state: StateSample, error: ErrorSample, q_ref: np.ndarray | None = None,
              references_heard: bool = False) -> str | None:
        if self.last_stamp is not None and stamp <= self.last_stamp:
            return self._reject("out_of_order_pairs")
        # a part is learned only where the state says it is usable, whatever the error's masks say
        error = ErrorSample(error.rbd_error, error.rbd_observed & state.valid, error.actuation_error,
                            error.actuation_observed & state.effort_valid)
        if not (error.rbd_observed.any() or error.actuation_observed.any()):
            return self._reject("invalid_samples")
        if self.gate is not None:
            paused = self.gate.check(stamp, state.q, np.where(error.rbd_observed, error.rbd_error, 0.0),
                                     np.where(error.actuation_observed, error.actuation_error, 0.0), q_ref,
                                     references_heard)
            if paused is not None:
                return self._reject(paused)
        x = learning_inputs(state.q, state.v, state.a, state.tau, state.tau_dot)[0]
        if not np.all(np.isfinite(x)):
            return self._reject("non_finite_inputs")
        self.last_stamp = stamp
        sample = (x, *self._targets(state.q, error))
        if self.heldout is not None and self.validation is not None and self.validation.held_back(stamp):
            self.heldout.add(*sample)
            return self._reject(HELD_BACK)
        self._keep_probe(x)
        if self.calibrating:
            self._buffer.append((stamp, sample))
            if len(self._buffer) >= self.calibration_samples:
                self._calibrate_and_learn_buffer()
            return None
        self.model_set.partial_fit_one(*sample)
        self._record(stamp)
        return None

    def _keep_probe(self, x: np.ndarray) -> None:
        """Reservoir sampling (Algorithm R): every learned x is in the probe set with equal probability."""
        self._probe_seen += 1
        if len(self._probes) < N_PROBES:
            self._probes.append(x.copy())
        else:
            k = int(self._probe_rng.integers(self._probe_seen))
            if k < N_PROBES:
                self._probes[k] = x.copy()

    @property
    def probe_inputs(self) -> np.ndarray:
        """The current uniform sample of the learned inputs x (k × n_inputs, k ≤ N_PROBES)."""
        return np.array(self._probes, dtype=float).reshape(len(self._probes), -1)

    def _targets(self, q: np.ndarray, error: ErrorSample) -> tuple[np.ndarray, ...]:
        """(Φ̃, mask, Γ, C) of one sample: Γ entries not observed are NaN (not learned)."""
        basis = contact_invariant_basis(self._dyn.foot_jacobians(q), self.robot.leg_joints)[None]
        rbd, observed = generalized_rbd_error(basis, error.rbd_error[None], error.rbd_observed[None],
                                              self.robot.leg_joints)
        gamma = np.where(error.actuation_observed, error.actuation_error, np.nan)
        return rbd[0], observed[0], gamma, leg_coupling(basis, self.robot.leg_joints)[0]

    def _record(self, stamp: int) -> None:
        if self.record_stamps:
            if self.n_learned >= len(self._stamps):
                self._stamps = np.concatenate([self._stamps, np.empty(len(self._stamps), dtype=np.int64)])
            self._stamps[self.n_learned] = stamp
        self.n_learned += 1

    def _calibrate_and_learn_buffer(self) -> None:
        stamps = [s for s, _ in self._buffer]
        X, rbd, observed, gamma, C = (np.array(a) for a in zip(*(sample for _, sample in self._buffer)))
        self._buffer.clear()
        self.calibration_samples = 0
        self.model_set.calibrate(X, rbd, observed, gamma)
        self.model_set.partial_fit(X, rbd, observed, gamma, None, C)  # = partial_fit_one on each, in order
        for s in stamps:
            self._record(s)

    def snapshot(self) -> Snapshot:
        """Deep copy of the model set (and learned stamps) for a writer thread; timed."""
        t0 = time.perf_counter()
        ms = copy.deepcopy(self.model_set)
        stamps = self.learned_stamps.copy() if self.record_stamps else None
        heldout = self.heldout.arrays() if self.heldout is not None else None
        return Snapshot(ms, self.n_learned, stamps, time.perf_counter() - t0, self.probe_inputs, heldout)


def warm_up(robot: RobotDescription, learner: str = "lwpr") -> float:
    """Compile (or load from numba's cache) the learner's code on a throwaway model set, so
    the first live sample is not late; returns the seconds it took."""
    t0 = time.perf_counter()
    ms = ModelSet.for_robot(robot, learner)
    x = probe_inputs(robot)
    ones = np.ones(ms.n_rbd, dtype=bool)
    for k in range(3):
        ms.partial_fit_one(x + 0.01 * k, np.zeros(ms.n_rbd), ones, np.zeros(ms.n_actuation))
    ms.predict_one(x)
    ms.partial_fit(np.array([x, x + 0.02]), np.zeros((2, ms.n_rbd)), np.ones((2, ms.n_rbd), bool),
                   np.zeros((2, ms.n_actuation)), None, np.zeros((2, N_BASE, ms.n_actuation)))
    return time.perf_counter() - t0


