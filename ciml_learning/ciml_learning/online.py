"""Online learning and model serving without ROS: the algorithms of the `online_learner`
and `model_server` nodes (docs/ARCHITECTURE.md §3), testable without rclpy.

Online learner (paper §III-D, LWPR learning at 250 Hz):

- StampPairer pairs each filtered state (/filtered_state: q, q̇, q̈ of eq. 12, τ, τ̇) with the
  measured error of the same header stamp (/model_error/measured: Φ̃' of eq. 11 and
  Γ of eq. 14). Topics are not ordered relative to each other over DDS, so either may
  come first; an item without a partner after `max_age` is dropped and counted.
- OnlineLearner feeds each valid pair, in increasing stamp order, to
  ModelSet.partial_fit_one with x = learning_inputs(q, q̇, q̈, τ, τ̇) and the measured Φ̃'
  turned into the set's targets Φ̃ = J'ᵀΦ̃' and leg coupling C with the contact-invariant
  basis at q (projection.generalized_rbd_error, leg_coupling — as the extraction does). Optionally the
  first `calibration_samples` valid pairs are buffered to calibrate the set's input and
  output scaling (ModelSet.calibrate), then learned in order. It can record the stamps
  it learned, in order: offline ModelSet.partial_fit on the same samples in the same
  order reproduces the online model (test/test_online_learning.py).
- SnapshotWriter saves snapshots from a worker thread: the learner's thread only pays a
  deep copy of the model set (timed, reported); serialisation, checksum and fsync run on
  the worker. Each snapshot is a new directory root/snapshot-NNNNNN (immutable once
  announced, so a server never reads a directory that is being rewritten), `root/latest`
  is a symlink to the newest, and only the newest `keep` are kept.

Model server:

- load_served_model loads and validates a model directory (ModelSet.load: version,
  allow-listed learner, robot names, the whole-model checksum; an announced model must
  carry that checksum; its predictions on its own training inputs stay within the robot's
  physical bounds) — any failure is a ModelFileError.
- predict_at_reference gives Φ̃' (18) and Γ (n_j) with variances at the reference (qᵈ, q̇ᵈ,
  q̈ᵈ and the torque it asks for, τ_ref, τ̇_ref: models.EpsilonFunction.predict), or the
  nominal model (see PredictedError): the set predicts Φ̃ = J'ᵀΦ̃' and the server publishes
  Φ̃' = J'⁻ᵀΦ̃ with the basis at qᵈ, so the message keeps the contact-invariant coordinates
  of /model_error/measured.
- LatestOnlyWorker runs the loading off the callback thread; the node swaps the served
  model in its own thread, so the old model serves until the new one is ready (no gap).
"""
from __future__ import annotations

import copy
import io
import os
import re
import shutil
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .conversions import ConversionError, _finite, _vector
from .dynamics import ReferenceState, ReferenceTorque, RigidBodyDynamics
from .errors import CimlError
from .extraction import learning_inputs
from .learners import learner_class
from .models import N_BASE, EpsilonFunction, ModelFileError, ModelSet, ModelSetError, default_scaling, read_metadata
from .projection import contact_invariant_basis, generalized_rbd_error, leg_coupling
from .robot import RobotDescription

STATE, ERROR = 0, 1
"""The two sides of a StampPairer: /filtered_state and /model_error/measured."""
SNAPSHOT_PREFIX = "snapshot-"
LATEST = "latest"
STAMPS_FILE = "learned_stamps.npy"
"""Optional file of a snapshot: int64 header stamps [ns] of the learned samples, in order."""
PROBE_FILE = "probe_inputs.npy"
"""File of a snapshot: float64 (k × n_inputs) learning inputs x drawn uniformly from the learned
samples (reservoir sampling), on which the model server checks the model's predictions."""
N_PROBES = 64


# ---------------------------------------------------------------------- messages → arrays
@dataclass
class StateSample:
    """The part of a filtered state the learner uses (Pinocchio q, v, q̈; τ, τ̇; `valid` flag)."""

    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    tau: np.ndarray
    tau_dot: np.ndarray
    valid: bool


@dataclass
class ErrorSample:
    """A measured model error in the robot's orders: Φ̃' (18) + mask, Γ (n_j) + mask."""

    rbd_error: np.ndarray
    rbd_observed: np.ndarray
    actuation_error: np.ndarray
    actuation_observed: np.ndarray


def _by_name(names, expected, what: str) -> np.ndarray:
    names = list(names)
    expected = list(expected)
    if len(names) != len(set(names)) or set(names) != set(expected):
        raise ConversionError(f"{what} names {names} do not match the robot's {expected}")
    index = {n: i for i, n in enumerate(names)}
    return np.array([index[n] for n in expected], dtype=int)


def model_error_sample(robot: RobotDescription, msg) -> ErrorSample:
    """A ciml_msgs/ModelError as arrays in robot.rbd_error_names / robot.joint_names order.

    Entries are matched by name; wrong or missing names, wrong sizes and non-finite
    values raise ConversionError (rclpy and rosbags messages alike).
    """
    nr, nj = len(msg.rbd_names), len(msg.actuation_names)
    perm_r = _by_name(msg.rbd_names, robot.rbd_error_names, "model_error rbd")
    perm_a = robot.joint_permutation(list(msg.actuation_names))
    phi = _vector(msg.rbd_error, nr, "model_error.rbd_error")[perm_r]
    gamma = _vector(msg.actuation_error, nj, "model_error.actuation_error")[perm_a]
    obs_r = np.asarray(msg.rbd_observed, dtype=bool)
    obs_a = np.asarray(msg.actuation_observed, dtype=bool)
    if obs_r.shape != (nr,) or obs_a.shape != (nj,):
        raise ConversionError(f"model_error: observed masks have {obs_r.size} and {obs_a.size} entries, "
                              f"expected {nr} and {nj}")
    _finite("model_error", phi, gamma)
    return ErrorSample(phi, obs_r[perm_r], gamma, obs_a[perm_a])


# ---------------------------------------------------------------------- pairing by stamp
class StampPairer:
    """Pairs items of two streams that carry the same header stamp [ns].

    add(side, stamp, item) returns (stamp, state_item, error_item) once both sides of a
    stamp are in, else None. Items wait at most max_age_ns behind the newest stamp seen
    on either side; older ones are dropped (counts["unmatched_states"/"unmatched_errors"]),
    as are items that arrive already that late. A second item of the same side and stamp
    is dropped (counts["duplicate_stamps"]). Memory is bounded by max_pending per side.
    """

    def __init__(self, max_age_ns: int, max_pending: int = 4096) -> None:
        if max_age_ns <= 0 or max_pending < 1:
            raise ValueError("max_age_ns and max_pending must be positive")
        self.max_age_ns = int(max_age_ns)
        self.max_pending = int(max_pending)
        self.pending: tuple[dict[int, Any], dict[int, Any]] = ({}, {})
        self.newest = None
        self.counts: Counter[str] = Counter()

    _NAMES = ("states", "errors")

    def add(self, side: int, stamp: int, item: Any) -> tuple[int, Any, Any] | None:
        stamp = int(stamp)
        mine, other = self.pending[side], self.pending[1 - side]
        if self.newest is not None and stamp < self.newest - self.max_age_ns:
            self.counts[f"unmatched_{self._NAMES[side]}"] += 1
            return None
        if stamp in mine:
            self.counts["duplicate_stamps"] += 1
            return None
        if self.newest is None or stamp > self.newest:
            self.newest = stamp
            self._evict()
        if stamp in other:
            partner = other.pop(stamp)
            return (stamp, item, partner) if side == STATE else (stamp, partner, item)
        mine[stamp] = item
        while len(mine) > self.max_pending:  # dicts keep insertion order: drop the oldest
            mine.pop(next(iter(mine)))
            self.counts[f"unmatched_{self._NAMES[side]}"] += 1
        return None

    def _evict(self) -> None:
        limit = self.newest - self.max_age_ns
        for side, pending in enumerate(self.pending):
            old = [s for s in pending if s < limit]
            for s in old:
                del pending[s]
            if old:
                self.counts[f"unmatched_{self._NAMES[side]}"] += len(old)

    def flush(self) -> None:
        """Drop everything pending (counted as unmatched)."""
        for side, pending in enumerate(self.pending):
            self.counts[f"unmatched_{self._NAMES[side]}"] += len(pending)
            pending.clear()


# ---------------------------------------------------------------------- learning
@dataclass
class Snapshot:
    """A frozen copy of the learner's model set, handed to the SnapshotWriter."""

    model_set: ModelSet
    samples: int                   # pairs learned when the copy was taken
    stamps: np.ndarray | None      # learned stamps [ns], in order (record_stamps only)
    copy_seconds: float            # time the learning thread spent copying
    probe_inputs: np.ndarray | None = None  # a uniform sample of the learned inputs x (k × n_inputs)


class OnlineLearner:
    """ModelSet.partial_fit_one on valid (state, error) pairs in increasing stamp order.

    learn() returns None when the pair was learned (or buffered for calibration), else
    the name of the rejection, which is also counted in `counts`:
    - "out_of_order_pairs": stamp not after the last learned one (learning order matters);
    - "invalid_samples": the state is not valid (near a contact change, filter warm-up,
      after a rejected input) or nothing in the error is observed;
    - "non_finite_inputs": x is not finite (cannot happen after the conversions' checks);
    - with a `gate` (learning_gate.LearningGate): its pause reasons (fall, tracking error,
      target beyond physical bounds, no reference, recovering).
    A uniform sample of the learned inputs (N_PROBES, reservoir sampling) goes with every
    snapshot, for the model server's bounds check.
    Γ entries whose actuation_observed flag is false are not learned (passed as NaN,
    which partial_fit_one skips per dimension); Φ̃' entries follow rbd_observed.
    """

    def __init__(self, robot: RobotDescription, model_set: ModelSet, calibration_samples: int = 0,
                 record_stamps: bool = False, gate=None) -> None:
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

    def learn(self, stamp: int, state: StateSample, error: ErrorSample) -> str | None:
        if self.last_stamp is not None and stamp <= self.last_stamp:
            return self._reject("out_of_order_pairs")
        if not state.valid or not (error.rbd_observed.any() or error.actuation_observed.any()):
            return self._reject("invalid_samples")
        if self.gate is not None:
            paused = self.gate.check(stamp, state.q, np.where(error.rbd_observed, error.rbd_error, 0.0),
                                     np.where(error.actuation_observed, error.actuation_error, 0.0))
            if paused is not None:
                return self._reject(paused)
        x = learning_inputs(state.q, state.v, state.a, state.tau, state.tau_dot)[0]
        if not np.all(np.isfinite(x)):
            return self._reject("non_finite_inputs")
        self.last_stamp = stamp
        self._keep_probe(x)
        sample = (x, *self._targets(state.q, error))
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
        return Snapshot(ms, self.n_learned, stamps, time.perf_counter() - t0, self.probe_inputs)


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


# ---------------------------------------------------------------------- background work
@dataclass
class WorkResult:
    item: Any
    value: Any = None
    error: str | None = None
    seconds: float = 0.0


class LatestOnlyWorker:
    """Runs fn(item) on one background thread; only the newest submitted item waits.

    submit() replaces a pending (not yet started) item: for model snapshots and model
    updates only the newest matters. Results (WorkResult) are collected by drain() from
    the owner's thread, so the owner never shares mutable state with the worker.
    Exceptions of fn become WorkResult.error (one line); the worker keeps running.
    """

    def __init__(self, fn: Callable[[Any], Any], name: str = "ciml-worker") -> None:
        self.fn = fn
        self._cond = threading.Condition()
        self._pending: list[Any] = []
        self._running = False
        self._closed = False
        self._results: deque[WorkResult] = deque()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    @property
    def busy(self) -> bool:
        with self._cond:
            return self._running or bool(self._pending)

    def submit(self, item: Any) -> bool:
        """Queue item; returns True if it replaced an item that had not started yet."""
        with self._cond:
            replaced = bool(self._pending)
            self._pending = [item]
            self._cond.notify()
            return replaced

    def drain(self) -> list[WorkResult]:
        out = []
        while self._results:
            out.append(self._results.popleft())
        return out

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._pending and not self._closed:
                    self._cond.wait()
                if not self._pending:
                    return
                item = self._pending.pop()
                self._running = True
            t0 = time.perf_counter()
            try:
                result = WorkResult(item, value=self.fn(item))
            except CimlError as err:
                result = WorkResult(item, error=str(err))
            except Exception as err:  # noqa: BLE001 - the worker must survive any failure and report it
                result = WorkResult(item, error=f"{type(err).__name__}: {err}")
            result.seconds = time.perf_counter() - t0
            self._results.append(result)
            with self._cond:
                self._running = False
                self._cond.notify_all()

    def close(self, timeout: float = 30.0) -> None:
        """Finish the pending item (if any) and stop the thread."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout)


# ---------------------------------------------------------------------- snapshots on disk
@dataclass
class SavedSnapshot:
    model_dir: str
    learner: str
    samples: int
    checksum: str
    write_seconds: float


class SnapshotWriter:
    """Numbered snapshot directories under `root` (module docstring); write() is what
    the worker thread runs. Numbering continues after existing snapshots."""

    def __init__(self, root: str, keep: int = 3) -> None:
        if keep < 1:
            raise ValueError("keep must be >= 1")
        self.root = os.path.abspath(os.path.expanduser(root))
        self.keep = int(keep)
        try:
            os.makedirs(self.root, exist_ok=True)
            existing = self.snapshots()
        except OSError as err:
            raise CimlError(f"cannot use snapshot folder {self.root}: {err.strerror or err}") from err
        self.seq = existing[-1][0] if existing else 0

    def snapshots(self) -> list[tuple[int, str]]:
        """(number, path) of the snapshot directories, oldest first."""
        out = []
        for name in os.listdir(self.root):
            m = re.fullmatch(rf"{SNAPSHOT_PREFIX}(\d+)", name)
            if m and os.path.isdir(os.path.join(self.root, name)):
                out.append((int(m.group(1)), os.path.join(self.root, name)))
        return sorted(out)

    def write(self, snap: Snapshot) -> SavedSnapshot:
        """Write the next snapshot directory (published whole: fileio.atomic_dir, the stamps in
        its manifest), then point `latest` at it (a symlink swapped with one rename), then
        remove snapshots beyond `keep`. Killed at any step: every snapshot-NNNNNN is complete."""
        from .fileio import clean_stale, fault_point, fsync_dir

        t0 = time.perf_counter()
        self.seq += 1
        name = f"{SNAPSHOT_PREFIX}{self.seq:06d}"
        path = os.path.join(self.root, name)
        clean_stale(self.root, rf"{SNAPSHOT_PREFIX}\d+|{LATEST}")
        extra = {}
        if snap.stamps is not None:
            buf = io.BytesIO()
            np.save(buf, snap.stamps.astype(np.int64), allow_pickle=False)
            extra[STAMPS_FILE] = buf.getvalue()
        if snap.probe_inputs is not None and len(snap.probe_inputs):
            buf = io.BytesIO()
            np.save(buf, snap.probe_inputs.astype(np.float64), allow_pickle=False)
            extra[PROBE_FILE] = buf.getvalue()
        snap.model_set.training_ = {**snap.model_set.training_, "source": "online_learner",
                                    "samples": int(snap.samples), "snapshot": self.seq}
        meta = snap.model_set.save(path, extra_files=extra, what="snapshot")
        tmp = os.path.join(self.root, f".{LATEST}.tmp-{os.getpid()}")
        if os.path.lexists(tmp):
            os.unlink(tmp)
        os.symlink(name, tmp)
        fault_point("rename")
        os.replace(tmp, os.path.join(self.root, LATEST))
        fsync_dir(self.root)
        for _, old in self.snapshots()[: -self.keep]:
            fault_point("cleanup")
            shutil.rmtree(old, ignore_errors=True)
        return SavedSnapshot(path, snap.model_set.learner, int(snap.samples), meta["checksum"],
                             time.perf_counter() - t0)


# ---------------------------------------------------------------------- serving
@dataclass
class ServedModel:
    """A validated model set as served by the model server."""

    name: str                 # "<learner>:<directory name>", the `source` of predictions
    model_dir: str
    model_set: ModelSet
    checksum: str
    rbd_learned: np.ndarray        # (18,) bool: entry of Φ̃' backed by learned models
    actuation_learned: np.ndarray  # (n_j,) bool
    dynamics: RigidBodyDynamics    # the server's own (the basis at the reference)
    epsilon: EpsilonFunction       # the set's predictions at a reference


def probe_inputs(robot: RobotDescription) -> np.ndarray:
    """Learning inputs x of the robot standing still without torque: a probe for validation."""
    q = robot.neutral_configuration().copy()
    q[7:] = robot.standing_joints
    zeros = np.zeros(robot.n_joints)
    return learning_inputs(q, np.zeros(robot.nv), np.zeros(robot.nv), zeros, zeros)[0]


def load_served_model(robot: RobotDescription, model_dir: str, checksum: str | None = None) -> ServedModel:
    """Load and validate a model directory for serving; ModelFileError (one line) if unusable.

    - ModelSet.load's checks: format version, allow-listed learner, model.json's own
      checksum, every file of its manifest, the robot's names.
    - Announced models (`checksum` not None: a /model_update) must carry the whole-model
      checksum (model.json's `checksum`, which covers the description and, through the
      manifest, every file); an empty or different one is refused.
    - Bounded predictions (check_predictions_within_bounds): on the model's own training
      inputs (the snapshot's probe_inputs.npy, else the set's input mean) and at the standing
      posture, every prediction finite and within the robot's physical bounds.
    """
    model_dir = os.path.abspath(os.path.expanduser(model_dir))
    meta = read_metadata(model_dir)
    stored = str(meta.get("checksum", ""))
    if checksum is not None:
        announced = str(checksum)
        if not announced:
            raise ModelFileError(f"{model_dir}: announced without a checksum (refused: only checksummed "
                                 "snapshots are served)")
        if stored != announced:
            raise ModelFileError(f"{model_dir}: model checksum {stored[:12]}… differs from the announced "
                                 f"{announced[:12]}… (replaced or tampered after the announcement)")
    ms = ModelSet.load(model_dir, robot)
    meta = read_metadata(model_dir)
    if str(meta.get("checksum", "")) != stored:
        raise ModelFileError(f"{model_dir} changed while it was being loaded")
    probes = [probe_inputs(robot), ms.input_mean_]
    if PROBE_FILE in meta["manifest"]:
        probes += list(_read_probe_file(model_dir, meta, ms))
    check_predictions_within_bounds(robot, ms, np.array(probes), model_dir)
    return served_model(robot, ms, f"{ms.learner}:{os.path.basename(model_dir)}", model_dir, stored)


def _read_probe_file(model_dir: str, meta: dict, ms: ModelSet) -> np.ndarray:
    from .models import read_model_file

    try:
        x = np.asarray(np.load(io.BytesIO(read_model_file(model_dir, meta, PROBE_FILE)), allow_pickle=False),
                       dtype=float)
    except (ValueError, OSError, EOFError, TypeError) as err:
        raise ModelFileError(f"{model_dir}/{PROBE_FILE} is not a readable npy ({err})") from None
    if x.ndim != 2 or x.shape[1] != len(ms.input_names) or not np.all(np.isfinite(x)):
        raise ModelFileError(f"{model_dir}/{PROBE_FILE}: shape {x.shape} or values unusable "
                             f"(expected finite (k, {len(ms.input_names)}))")
    return x


def check_predictions_within_bounds(robot: RobotDescription, ms: ModelSet, inputs: np.ndarray,
                                    where: str = "model") -> None:
    """ModelFileError unless every prediction (Φ̃ = J'ᵀΦ̃' and Γ, means) at the rows of `inputs`
    is finite and within physical_bounds (base force m·g, base torque m·g·leg span, joint
    torques their limits): a model predicting more than the robot can produce has learned a
    fall or was corrupted (e.g. scaled)."""
    from .physical_bounds import physical_bounds

    bounds = physical_bounds(robot)
    for x in np.atleast_2d(inputs):
        rbd, _, gamma, _ = ms.predict_one(x)
        bad = bounds.generalized_violation(rbd) or bounds.actuation_violation(gamma)
        if bad:
            raise ModelFileError(f"{where}: prediction beyond physical bounds on its own training inputs ({bad})")


def served_model(robot: RobotDescription, ms: ModelSet, name: str, model_dir: str = "",
                 checksum: str = "") -> ServedModel:
    """A ServedModel of a validated set: a Φ̃' entry counts as learned when the models it is
    made of are (the base entry's wrench model; a foot's: its leg's joint models)."""
    learned = np.array([m is not None for m in ms.models_], dtype=bool)
    rbd = np.concatenate([learned[:N_BASE]] + [np.repeat(learned[N_BASE + np.asarray(leg)].all(), 3)
                                               for leg in robot.leg_joints])
    return ServedModel(name=name, model_dir=model_dir, model_set=ms, checksum=checksum, rbd_learned=rbd,
                       actuation_learned=learned[ms.n_rbd:], dynamics=RigidBodyDynamics(robot),
                       epsilon=EpsilonFunction(robot, ms))


@dataclass
class PredictedError:
    """What the model server publishes on /model_error/predicted.

    Learned model: the set's means and predictive variances [N², Nm²]; observed = the
    dimension has a learned model (an unlearned dimension predicts 0 with its prior
    variance, output_scale², as ModelSet.predict_one does).
    Nominal model (no model loaded, or a non-finite prediction): zeros, all observed
    flags false, and a prior variance from default_scaling(robot): (5 % of the weight
    [N], ×0.1 m [Nm], per foot a quarter; 5 % of each torque limit [Nm])² — large
    compared with a learned model's variance, so "we do not know" is explicit.
    """

    source: str
    rbd_error: np.ndarray
    rbd_variance: np.ndarray
    rbd_observed: np.ndarray
    actuation_error: np.ndarray
    actuation_variance: np.ndarray
    actuation_observed: np.ndarray
    fallback: str | None = None    # why nominal was served ("no_model", "non_finite_prediction")


NOMINAL = "nominal"


def nominal_prediction(robot: RobotDescription, fallback: str | None = None) -> PredictedError:
    _, _, out_scale = default_scaling(robot)
    foot = 0.05 * robot.total_mass * 9.81 / robot.n_feet
    rbd_var = np.concatenate([out_scale[:N_BASE], np.full(3 * robot.n_feet, foot)]) ** 2
    nr, nj = len(robot.rbd_error_names), robot.n_joints
    return PredictedError(NOMINAL, np.zeros(nr), rbd_var, np.zeros(nr, bool),
                          np.zeros(nj), out_scale[-nj:] ** 2, np.zeros(nj, bool), fallback)


def predict_at_reference(robot: RobotDescription, served: ServedModel | None, ref: ReferenceState,
                         reference_torque: ReferenceTorque | None = None) -> PredictedError:
    """Φ̃' and Γ (with variances) at a reference point (EpsilonFunction.predict: the state's
    learning inputs with the torque τ_ref, τ̇_ref the reference asks for); nominal when no
    model is served or anything predicted is non-finite. Never returns NaN.

    reference_torque: the reference stream's ReferenceTorque (the caller's, so τ̇_ref runs on
    across a model swap; default: the served model's own).
    The set predicts Φ̃ = J'ᵀΦ̃'; Φ̃' = J'⁻ᵀΦ̃ with the basis at qᵈ (eq. 8), its variance
    propagated assuming independent dimensions."""
    if served is None:
        return nominal_prediction(robot, "no_model")
    q = np.asarray(ref.q, float)
    # one Jacobian pass per reference: τ_ref's contact Jacobian and the basis share it
    jacobians = served.dynamics.foot_jacobians(q) if np.all(np.isfinite(q)) else None
    out = served.epsilon.predict(ref, reference_torque, jacobians)
    if out is None:
        return nominal_prediction(robot, "non_finite_reference")
    rbd, rbd_var, gamma, gamma_var = out
    inverse_basis_t = np.linalg.inv(contact_invariant_basis(jacobians, robot.leg_joints).T)
    phi, phi_var = inverse_basis_t @ rbd, inverse_basis_t ** 2 @ rbd_var
    if not all(np.all(np.isfinite(z)) for z in (phi, phi_var, gamma, gamma_var)):
        return nominal_prediction(robot, "non_finite_prediction")
    return PredictedError(served.name, phi, phi_var, served.rbd_learned.copy(), gamma, gamma_var,
                          served.actuation_learned.copy())
