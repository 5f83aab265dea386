"""The per-dimension model set of the model error, its file format, and ε at a reference.

A ModelSet holds one independent learner per output dimension (paper §III-D):

- 18 rigid-body models of the contact-invariant error Φ̃' (base wrench, then x/y/z of
  each foot; names robot.rbd_error_names). The base wrench models take the whole input x
  of eq. (12): roll, pitch, joint positions, q̇, q̈ (50 for HyQ; names
  extraction.learning_input_names). A foot's models take roll, pitch and its own leg's
  q, q̇, q̈ (11; rbd_input_names): a foot's entries are observed only while it swings,
  where they hold the swing leg's own error — with the other legs' joints as inputs a
  model learns the gait those legs happened to walk, and mispredicts on any other gait
  (measured with LWPR trained as in tools/experiment.py, 20 s closed loop of the rear
  walk on the default gap: feedback effort 16 % above nominal with all 50 inputs, 25 %
  below with the leg's own);
- 12 actuation models of Γ = τ − u (eq. 14), one per joint i (robot.joint_names), inputs
  (q_i, q̇_i, q̈_i) — the columns "q_<joint>", "qd_<joint>", "qdd_<joint>" of x.

Combined, they give the model error the controller adds (eq. 17):

    ε(q, q̇, q̈) = J'(q)ᵀ Φ̃'(x) − Sᵀ Γ(x)

Observed mask: a foot's three entries of Φ̃' are observed only while that foot swings
(eq. 11; ExtractionResult.rbd_observed); each rigid-body model learns only from samples
that are `valid` and where its entry is observed. The actuation models learn from every
valid sample. A dimension with no usable sample keeps no model: it predicts zero (the
nominal model) with its prior variance, as every learner does away from its data.

Standardisation happens inside the set: inputs are centred and scaled per column
(input_mean_, input_scale_), outputs only scaled (output_scale_, their RMS), never
shifted — zero stays "no error", so the learners' zero-mean fallback is the nominal
model. Learners see standardised data; predictions are returned in SI units
(N, Nm; variances in N², Nm²).

API for online use (the online_learner and model_server nodes build on this):

    ms = ModelSet.for_robot(robot, "lwpr")            # empty set, default scaling
    ms.calibrate(X, rbd_error, rbd_observed, actuation_error, valid)   # optional, first
    ms.partial_fit_one(x, phi, observed, gamma)      # one sample (x: 50, phi: 18,
                                                     #   observed: 18 bool, gamma: 12)
    ms.partial_fit(X, Phi, Observed, Gamma, valid)   # a batch, same result as one by one
    rbd, rbd_var, act, act_var = ms.predict_one(x)   # fast single-sample prediction
    eps = EpsilonFunction(robot, ms); eps.epsilon(q, v, a)   # ε at a state, eq. (17)
    ms.save(model_dir)                               # atomic snapshot (npz + json)
    ms = ModelSet.load(model_dir, robot)             # validated, refuses bad files

partial_fit needs an incremental learner (LWPR); the sparse GP is batch-only (fit).
A ModelSet is not thread-safe: the online learner should save a snapshot from its own
thread and then announce it (/model_update); the server loads it after the announcement.

File format (model_dir/, both written atomically, the npz first):

    model.npz   arrays only, read with allow_pickle=False: input_mean, input_scale,
                output_scale, and "dimNN.<key>" for each learned dimension NN
                (learner state, see the learners' get_state)
    model.json  format_version, learner, kernel, hyper-parameters, input/output names,
                the robot's joint and foot names, training bags and sample counts,
                per-dimension summaries, and the npz's sha256 and size

Loading checks the version, the learner against an allow-list, the robot's names and the
checksum, then rebuilds each learner from its arrays — no pickle, no GPy save/load, no
name from the file is ever evaluated. Any mismatch raises ModelFileError (one line).
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import time
import zipfile
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import CimlError
from .learners import Learner, LearnerError, learner_class

FORMAT_VERSION = 2
"""2: per-dimension input selection (rbd_input_names); version 1 files are refused."""
MODEL_JSON = "model.json"
MODEL_NPZ = "model.npz"
KIND = "ciml_model_set"
KERNELS = {"lwpr": "gaussian_receptive_fields", "sgpr": "matern32_ard"}

DEFAULT_PARAMS: dict[str, dict[str, dict[str, Any]]] = {
    # Hyper-parameters per learner and group, in standardised units (unit-variance inputs,
    # unit-RMS outputs). Groups: "rbd" the base wrench models (50-D inputs), "foot" a foot's
    # models (11-D), "actuation". RBD: a diagonal metric, at most 3 PLS projections and wide
    # initial fields (gait data lie near low-dimensional cycles; the squared distance between
    # two phases a tenth of a cycle apart is ~20 in 50 standardised dimensions, so D = 0.2
    # puts a few tens of fields along a cycle; in 11-D, D = 0.8 does, and generalised best to
    # new gaits among 0.2–2 in closed loop: rear/side walks, trot). Actuation inputs
    # are 3-D: a full metric. Offline fit() visits the samples in random order (shuffle;
    # LWPR assumes no ordering, and time-ordered gait data otherwise drift the fields);
    # online partial_fit() takes them as they come. The sparse GP fits its hyper-parameters
    # on 1,500 random samples per dimension (learners/sgpr.py explains why).
    "lwpr": {
        "rbd": {"init_D": 0.2, "diag_only": True, "init_alpha": 10.0, "w_gen": 0.1, "w_prune": 0.95,
                "max_projections": 3, "penalty": 1e-6, "max_rfs": 1500, "n_epochs": 1, "shuffle": True},
        "foot": {"init_D": 0.8, "diag_only": True, "init_alpha": 10.0, "w_gen": 0.1, "w_prune": 0.95,
                 "max_projections": 3, "penalty": 1e-6, "max_rfs": 1500, "n_epochs": 1, "shuffle": True},
        "actuation": {"init_D": 10.0, "diag_only": False, "init_alpha": 50.0, "w_gen": 0.2, "w_prune": 0.95,
                      "penalty": 1e-6, "max_rfs": 400, "n_epochs": 2, "shuffle": True},
    },
    "sgpr": {
        "rbd": {"n_inducing": 250, "n_hyper_samples": 1500, "max_iters": 80},
        "foot": {"n_inducing": 250, "n_hyper_samples": 1500, "max_iters": 80},
        "actuation": {"n_inducing": 100, "n_hyper_samples": 1500, "max_iters": 100},
    },
}
"""Default hyper-parameters (paper: 250 inducing inputs per RBD and 100 per actuation
dimension). Override per group with ModelSet(..., rbd_params=..., actuation_params=...,
foot_params=...)."""
N_BASE = 6
"""The first rigid-body dimensions: the base wrench (group "rbd"); the others are the feet's."""

MIN_SAMPLES = 10
"""A dimension with fewer usable samples than this keeps no model (zero error)."""


class ModelFileError(CimlError):
    """A model directory that cannot be used: missing, truncated, tampered, wrong version or robot."""


class ModelSetError(CimlError):
    """Bad input to a model set (shapes, learner without partial_fit, ...)."""


@dataclass
class Prediction:
    """Predicted errors (SI units) and their variances, one row per input."""

    rbd: np.ndarray            # N × 18, Φ̃' [N, Nm]
    rbd_var: np.ndarray        # N × 18 [N², Nm²]
    actuation: np.ndarray      # N × n_j, Γ [Nm]
    actuation_var: np.ndarray  # N × n_j [Nm²]


def actuation_input_names(joint: str) -> tuple[str, str, str]:
    """Names of joint i's actuation-model inputs among the learning inputs (q_i, q̇_i, q̈_i)."""
    return (f"q_{joint}", f"qd_{joint}", f"qdd_{joint}")


def rbd_input_names(robot) -> dict[str, tuple[str, ...]]:
    """Inputs of each rigid-body model (module docstring): all learning inputs for the base
    wrench, roll, pitch and the leg's own q, q̇, q̈ for a foot's entries."""
    from .extraction import learning_input_names

    names = tuple(learning_input_names(robot))
    out = {}
    for d in robot.rbd_error_names[:N_BASE]:
        out[d] = names
    for f, leg in enumerate(robot.leg_joints):
        own = ("base_roll", "base_pitch") + tuple(
            n for j in leg for n in actuation_input_names(robot.joint_names[j]))
        own = tuple(sorted(own, key=names.index))
        for d in robot.rbd_error_names[N_BASE + 3 * f:N_BASE + 3 * f + 3]:
            out[d] = own
    return out


def default_scaling(robot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Input mean/scale and output scales for a set that learns online from scratch.

    Derived from the robot description only (no data): joints centred on the standing
    posture with a sixth of their range as scale, roll/pitch 0.1 rad, velocities 0.5 m/s,
    0.5 rad/s (base) and 2 rad/s (joints), accelerations 5 m/s², 5 rad/s², 30 rad/s²;
    outputs 5 % of the robot's weight (base forces; per foot: a quarter), 5 % of
    weight × 0.1 m (base torques) and 5 % of each joint's torque limit.
    calibrate() on real data replaces these.
    """
    from .extraction import learning_input_names

    names = learning_input_names(robot)
    mean = np.zeros(len(names))
    scale = np.ones(len(names))
    lo, hi = robot.position_limits
    span = np.where(np.isfinite(hi - lo) & (hi - lo > 0), hi - lo, 2.0)
    index = {n: i for i, n in enumerate(names)}
    scale[index["base_roll"]] = scale[index["base_pitch"]] = 0.1
    for j, joint in enumerate(robot.joint_names):
        q, qd, qdd = (index[n] for n in actuation_input_names(joint))
        mean[q] = robot.standing_joints[j]
        scale[q] = span[j] / 6.0
        scale[qd] = 2.0
        scale[qdd] = 30.0
    for k, dof in enumerate(robot.dof_names[:6]):
        scale[index[f"qd_{dof}"]] = 0.5
        scale[index[f"qdd_{dof}"]] = 5.0
    weight = robot.total_mass * 9.81
    out = np.concatenate([
        np.full(3, 0.05 * weight), np.full(3, 0.05 * weight * 0.1),
        np.full(3 * robot.n_feet, 0.05 * weight / robot.n_feet),
        0.05 * np.where(robot.torque_limits > 0, robot.torque_limits, 100.0),
    ])
    return mean, scale, out


class ModelSet:
    """18 rigid-body + n_j actuation models of the model error (module docstring).

    Attributes (after construction): learner, input_names, rbd_names, joint_names,
    foot_frames, rbd_params (base wrench), foot_params, actuation_params, rbd_inputs (rbd
    name → its input names; default all), input_index (per output dimension, its columns of x).
    Learned/calibrated state: input_mean_, input_scale_, output_scale_ (18 + n_j),
    models_ (list of Learner or None, RBD dimensions first), n_samples_ (per dimension),
    training_ (dict of provenance written to model.json).
    """

    def __init__(self, learner: str, input_names, rbd_names, joint_names, foot_frames,
                 rbd_params: dict | None = None, actuation_params: dict | None = None,
                 rbd_inputs: dict | None = None, foot_params: dict | None = None) -> None:
        self.learner = learner
        cls = learner_class(learner)
        self.input_names = tuple(input_names)
        self.rbd_names = tuple(rbd_names)
        self.joint_names = tuple(joint_names)
        self.foot_frames = tuple(foot_frames)
        defaults = DEFAULT_PARAMS[learner]
        self.rbd_params = {**defaults["rbd"], **(rbd_params or {})}
        self.foot_params = {**defaults["foot"], **(foot_params or {})}
        self.actuation_params = {**defaults["actuation"], **(actuation_params or {})}
        for p in (self.rbd_params, self.foot_params, self.actuation_params):
            cls.from_params(p)  # validates names and values now, not after an hour of training
        index = {n: i for i, n in enumerate(self.input_names)}
        everything = tuple(self.input_names)
        self.rbd_inputs = {d: tuple((rbd_inputs or {}).get(d, everything)) for d in self.rbd_names}
        try:
            self.input_index = [np.array([index[n] for n in self.rbd_inputs[d]], dtype=np.int64)
                                for d in self.rbd_names]
            self.input_index += [np.array([index[n] for n in actuation_input_names(j)], dtype=np.int64)
                                 for j in self.joint_names]
        except (KeyError, TypeError) as err:
            raise ModelSetError(f"a model's input {err} is not a learning input") from None
        n_in = len(self.input_names)
        self.input_mean_ = np.zeros(n_in)
        self.input_scale_ = np.ones(n_in)
        self.output_scale_ = np.ones(self.n_outputs)
        self.models_: list[Learner | None] = [None] * self.n_outputs
        self.n_samples_ = np.zeros(self.n_outputs, dtype=np.int64)
        self.training_: dict[str, Any] = {}

    @classmethod
    def for_robot(cls, robot, learner: str, rbd_params: dict | None = None,
                  actuation_params: dict | None = None, foot_params: dict | None = None) -> "ModelSet":
        """An empty set for a robot, with default_scaling(robot) until calibrated."""
        from .extraction import learning_input_names

        ms = cls(learner, learning_input_names(robot), robot.rbd_error_names, robot.joint_names,
                 robot.foot_frames, rbd_params, actuation_params, rbd_input_names(robot), foot_params)
        ms.input_mean_, ms.input_scale_, ms.output_scale_ = default_scaling(robot)
        return ms

    # ------------------------------------------------------------------ names and sizes
    @property
    def n_rbd(self) -> int:
        return len(self.rbd_names)

    @property
    def n_actuation(self) -> int:
        return len(self.joint_names)

    @property
    def n_outputs(self) -> int:
        return self.n_rbd + self.n_actuation

    @property
    def output_names(self) -> tuple[str, ...]:
        return self.rbd_names + self.joint_names

    def dimension_kind(self, i: int) -> str:
        return "rbd" if i < self.n_rbd else "actuation"

    def is_fitted(self) -> bool:
        return any(m is not None for m in self.models_)

    def _params(self, i: int) -> dict:
        if i < N_BASE:
            return self.rbd_params
        return self.foot_params if i < self.n_rbd else self.actuation_params

    def new_learner(self, i: int) -> Learner:
        """A fresh learner for output dimension i with its group's hyper-parameters."""
        return learner_class(self.learner).from_params(self._params(i))

    # ------------------------------------------------------------------ data handling
    def _check_data(self, X, rbd_error, rbd_observed, actuation_error, valid):
        X = np.asarray(X, dtype=float)
        n = len(X)
        rbd_error = np.asarray(rbd_error, dtype=float)
        rbd_observed = np.asarray(rbd_observed, dtype=bool)
        actuation_error = np.asarray(actuation_error, dtype=float)
        valid = np.ones(n, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
        shapes = {"X": (X.shape, (n, len(self.input_names))), "rbd_error": (rbd_error.shape, (n, self.n_rbd)),
                  "rbd_observed": (rbd_observed.shape, (n, self.n_rbd)),
                  "actuation_error": (actuation_error.shape, (n, self.n_actuation)), "valid": (valid.shape, (n,))}
        bad = {k: v[0] for k, v in shapes.items() if v[0] != v[1]}
        if bad:
            raise ModelSetError(f"data shapes {bad} do not match {len(self.input_names)} inputs, "
                                f"{self.n_rbd} RBD and {self.n_actuation} actuation outputs")
        valid = valid & np.all(np.isfinite(X), axis=1)
        return X, rbd_error, rbd_observed, actuation_error, valid

    def _usable_rows(self, i: int, rbd_error, rbd_observed, actuation_error, valid) -> np.ndarray:
        if i < self.n_rbd:
            return valid & rbd_observed[:, i] & np.isfinite(rbd_error[:, i])
        return valid & np.isfinite(actuation_error[:, i - self.n_rbd])

    def calibrate(self, X, rbd_error, rbd_observed, actuation_error, valid=None) -> "ModelSet":
        """Set the input mean/scale and output scales from data (before any learning)."""
        if self.is_fitted():
            raise ModelSetError("calibrate() must come before learning: the models use the old scaling")
        X, rbd_error, rbd_observed, actuation_error, valid = self._check_data(
            X, rbd_error, rbd_observed, actuation_error, valid)
        if valid.sum() >= 2:
            Xv = X[valid]
            self.input_mean_ = Xv.mean(axis=0)
            std = Xv.std(axis=0)
            self.input_scale_ = np.where(std > 1e-9, std, 1.0)
        targets = np.hstack([rbd_error, actuation_error])
        for i in range(self.n_outputs):
            rows = self._usable_rows(i, rbd_error, rbd_observed, actuation_error, valid)
            if rows.any():
                rms = float(np.sqrt(np.mean(targets[rows, i] ** 2)))
                self.output_scale_[i] = rms if rms > 1e-9 else 1.0
        return self

    def standardize(self, X: np.ndarray) -> np.ndarray:
        """Standardised learning inputs, (X − input_mean_) / input_scale_."""
        return (np.asarray(X, dtype=float) - self.input_mean_) / self.input_scale_

    def _dim_inputs(self, i: int, Xs: np.ndarray) -> np.ndarray:
        return Xs[..., self.input_index[i]]

    # ------------------------------------------------------------------ learning
    def fit(self, X, rbd_error, rbd_observed, actuation_error, valid=None, n_jobs: int = 1,
            progress: bool = False, calibrate: bool = True) -> "ModelSet":
        """Learn every dimension from scratch, in parallel (training.fit_dimensions).

        X: learning inputs (N × 50, eq. 12); rbd_error: Φ̃' (N × 18, anything where
        unobserved); rbd_observed: (N × 18) bool; actuation_error: Γ (N × n_j);
        valid: (N,) bool. Returns self.
        """
        from .training import fit_dimensions

        X, rbd_error, rbd_observed, actuation_error, valid = self._check_data(
            X, rbd_error, rbd_observed, actuation_error, valid)
        self.models_ = [None] * self.n_outputs
        if calibrate:
            self.calibrate(X, rbd_error, rbd_observed, actuation_error, valid)
        Xs = self.standardize(X)
        targets = np.hstack([rbd_error, actuation_error])
        jobs = []
        self.n_samples_ = np.zeros(self.n_outputs, dtype=np.int64)
        for i in range(self.n_outputs):
            rows = self._usable_rows(i, rbd_error, rbd_observed, actuation_error, valid)
            self.n_samples_[i] = int(rows.sum())
            if self.n_samples_[i] >= MIN_SAMPLES:
                jobs.append((i, self._dim_inputs(i, Xs[rows]), targets[rows, i] / self.output_scale_[i]))
        fitted = fit_dimensions(self.learner, [self._params(i) for i, _, _ in jobs], jobs, n_jobs=n_jobs,
                                progress=progress, names=[self.output_names[i] for i, _, _ in jobs])
        for (i, _, _), model in zip(jobs, fitted):
            self.models_[i] = model
        return self

    def _require_incremental(self) -> None:
        if not learner_class(self.learner).supports_partial_fit:
            raise ModelSetError(f"learner {self.learner!r} has no partial_fit (batch only); use 'lwpr' online")

    def partial_fit(self, X, rbd_error, rbd_observed, actuation_error, valid=None) -> "ModelSet":
        """Incremental learning on a batch of samples in time order; returns self.

        Identical to calling partial_fit_one on each valid sample in order (each dimension
        is an independent learner, so it is updated with its own rows as one batch).
        """
        self._require_incremental()
        X, rbd_error, rbd_observed, actuation_error, valid = self._check_data(
            X, rbd_error, rbd_observed, actuation_error, valid)
        Xs = self.standardize(X)
        targets = np.hstack([rbd_error, actuation_error])
        for i in range(self.n_outputs):
            rows = self._usable_rows(i, rbd_error, rbd_observed, actuation_error, valid)
            if not rows.any():
                continue
            if self.models_[i] is None:
                self.models_[i] = self.new_learner(i)
            self.models_[i].partial_fit(self._dim_inputs(i, Xs[rows]), targets[rows, i] / self.output_scale_[i])
            self.n_samples_[i] += int(rows.sum())
        return self

    def partial_fit_one(self, x: np.ndarray, rbd_error: np.ndarray, rbd_observed: np.ndarray,
                        actuation_error: np.ndarray) -> None:
        """Learn from one valid sample (online, 250 Hz): x (50,), Φ̃' (18,), mask (18,), Γ (n_j,).

        Non-finite values are skipped per dimension (never learned)."""
        self._require_incremental()
        x = np.asarray(x, dtype=float)
        if not np.all(np.isfinite(x)):
            return
        xs = (x - self.input_mean_) / self.input_scale_
        n_rbd = self.n_rbd
        for i in range(self.n_outputs):
            if i < n_rbd:
                if not rbd_observed[i]:
                    continue
                y = rbd_error[i]
            else:
                y = actuation_error[i - n_rbd]
            xi = xs[self.input_index[i]]
            if not np.isfinite(y):
                continue
            model = self.models_[i]
            if model is None:
                model = self.models_[i] = self.new_learner(i)
            model.update(xi, y / self.output_scale_[i])
            self.n_samples_[i] += 1

    # ------------------------------------------------------------------ prediction
    def predict(self, X: np.ndarray, return_var: bool = True) -> Prediction:
        """Φ̃' and Γ (and variances) at learning inputs X (N × 50 or 50,)."""
        X = np.atleast_2d(np.asarray(X, dtype=float))
        if X.shape[1] != len(self.input_names):
            raise ModelSetError(f"X has {X.shape[1]} columns, the model set expects {len(self.input_names)}")
        if not np.all(np.isfinite(X)):
            raise ModelSetError("X contains non-finite values")
        Xs = self.standardize(X)
        mean = np.zeros((len(X), self.n_outputs))
        var = np.zeros((len(X), self.n_outputs))
        for i, model in enumerate(self.models_):
            s = self.output_scale_[i]
            if model is None:
                var[:, i] = s * s  # the prior of an unlearned dimension: zero error, unit RMS
                continue
            if return_var:
                m, sd = model.predict(self._dim_inputs(i, Xs), return_std=True)
                var[:, i] = (sd * s) ** 2
            else:
                m = model.predict(self._dim_inputs(i, Xs))
            mean[:, i] = m * s
        n = self.n_rbd
        return Prediction(mean[:, :n], var[:, :n], mean[:, n:], var[:, n:])

    def predict_one(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Fast single-sample prediction: (Φ̃' (18), var (18), Γ (n_j), var (n_j)), SI units.

        No input checks beyond the caller's (x must be finite, 50 entries)."""
        xs = (np.asarray(x, dtype=float) - self.input_mean_) / self.input_scale_
        mean = np.zeros(self.n_outputs)
        var = np.empty(self.n_outputs)
        n_rbd = self.n_rbd
        for i, model in enumerate(self.models_):
            s = self.output_scale_[i]
            if model is None:
                var[i] = s * s
                continue
            m, sd = model.predict_one(xs[self.input_index[i]])
            mean[i] = m * s
            var[i] = (sd * s) ** 2
        return mean[:n_rbd], var[:n_rbd], mean[n_rbd:], var[n_rbd:]

    # ------------------------------------------------------------------ files
    def check_robot(self, robot, where: str = "model") -> None:
        """Raise ModelFileError unless the set's names match the robot's."""
        from .extraction import learning_input_names

        for what, mine, theirs in (("joints", self.joint_names, tuple(robot.joint_names)),
                                   ("feet", self.foot_frames, tuple(robot.foot_frames)),
                                   ("RBD outputs", self.rbd_names, tuple(robot.rbd_error_names)),
                                   ("inputs", self.input_names, tuple(learning_input_names(robot)))):
            if mine != theirs:
                raise ModelFileError(f"{where} was trained for a different robot: {what} {list(mine)} "
                                     f"but the robot has {list(theirs)}")

    def metadata(self, npz_sha256: str, npz_bytes: int) -> dict[str, Any]:
        dims = []
        for i, model in enumerate(self.models_):
            entry = {"name": self.output_names[i], "kind": self.dimension_kind(i), "samples": int(self.n_samples_[i]),
                     "output_scale": float(self.output_scale_[i]), "learned": model is not None}
            if model is not None and hasattr(model, "summary"):
                entry["summary"] = model.summary()
            dims.append(entry)
        return {
            "format_version": FORMAT_VERSION,
            "kind": KIND,
            "learner": self.learner,
            "kernel": KERNELS[self.learner],
            "params": {"rbd": self.rbd_params, "foot": self.foot_params, "actuation": self.actuation_params},
            "inputs": {"names": list(self.input_names),
                       "rbd": {d: list(self.rbd_inputs[d]) for d in self.rbd_names},
                       "actuation": {j: list(actuation_input_names(j)) for j in self.joint_names}},
            "outputs": {"rbd": list(self.rbd_names), "actuation": list(self.joint_names),
                        "units": {"rbd": "N (forces), Nm (base torques)", "actuation": "Nm"}},
            "robot": {"joint_names": list(self.joint_names), "foot_frames": list(self.foot_frames)},
            "training": self.training_,
            "dimensions": dims,
            "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
            "npz": {"file": MODEL_NPZ, "sha256": npz_sha256, "bytes": npz_bytes},
        }

    def to_arrays(self) -> dict[str, np.ndarray]:
        arrays = {"input_mean": self.input_mean_, "input_scale": self.input_scale_,
                  "output_scale": self.output_scale_, "n_samples": self.n_samples_}
        for i, model in enumerate(self.models_):
            if model is not None:
                for key, value in model.get_state().items():
                    arrays[f"dim{i:02d}.{key}"] = np.asarray(value)
        return arrays

    def save(self, model_dir: str) -> dict[str, Any]:
        """Write model_dir/model.npz then model_dir/model.json, each atomically; returns the metadata."""
        from .fileio import atomic_write_bytes, atomic_write_json

        buf = io.BytesIO()
        np.savez(buf, **self.to_arrays())
        data = buf.getvalue()
        meta = self.metadata(hashlib.sha256(data).hexdigest(), len(data))
        os.makedirs(model_dir, exist_ok=True)
        atomic_write_bytes(os.path.join(model_dir, MODEL_NPZ), data)
        atomic_write_json(os.path.join(model_dir, MODEL_JSON), meta)
        return meta

    @classmethod
    def load(cls, model_dir: str, robot=None) -> "ModelSet":
        """Read and validate a model directory; with `robot`, also check it was trained for it."""
        meta = read_metadata(model_dir)
        data = _read_npz_bytes(model_dir, meta)
        try:
            with np.load(io.BytesIO(data), allow_pickle=False) as npz:
                arrays = {k: npz[k] for k in npz.files}
        except (zipfile.BadZipFile, ValueError, OSError, EOFError) as err:
            raise ModelFileError(f"{model_dir}/{MODEL_NPZ} is not a readable npz ({err})") from None
        try:
            ms = cls(meta["learner"], meta["inputs"]["names"], meta["outputs"]["rbd"], meta["outputs"]["actuation"],
                     meta["robot"]["foot_frames"], meta["params"]["rbd"], meta["params"]["actuation"],
                     meta["inputs"]["rbd"], meta["params"]["foot"])
        except KeyError as err:
            raise ModelFileError(f"{model_dir}/{MODEL_JSON} lacks {err}") from None
        except (TypeError, AttributeError, ValueError) as err:
            raise ModelFileError(f"{model_dir}/{MODEL_JSON}: malformed ({err})") from None
        except (LearnerError, ModelSetError) as err:
            raise ModelFileError(f"{model_dir}/{MODEL_JSON}: {err}") from None
        if robot is not None:
            ms.check_robot(robot, where=f"model {model_dir}")
        try:
            for key, size in (("input_mean", len(ms.input_names)), ("input_scale", len(ms.input_names)),
                              ("output_scale", ms.n_outputs), ("n_samples", ms.n_outputs)):
                a = arrays[key]
                if a.shape != (size,) or not np.all(np.isfinite(a)):
                    raise ModelFileError(f"{model_dir}/{MODEL_NPZ}: {key} has shape {a.shape}, expected ({size},)")
            if np.any(arrays["input_scale"] <= 0) or np.any(arrays["output_scale"] <= 0):
                raise ModelFileError(f"{model_dir}/{MODEL_NPZ}: scales must be positive")
            ms.input_mean_ = arrays["input_mean"].astype(float)
            ms.input_scale_ = arrays["input_scale"].astype(float)
            ms.output_scale_ = arrays["output_scale"].astype(float)
            ms.n_samples_ = arrays["n_samples"].astype(np.int64)
            cls_ = learner_class(ms.learner)
            dims = meta["dimensions"]
            if len(dims) != ms.n_outputs:
                raise ModelFileError(f"{model_dir}/{MODEL_JSON}: {len(dims)} dimensions, expected {ms.n_outputs}")
            for i, entry in enumerate(dims):
                if not isinstance(entry, dict) or entry.get("name") != ms.output_names[i]:
                    raise ModelFileError(f"{model_dir}/{MODEL_JSON}: dimension {i} is not {ms.output_names[i]!r}")
                prefix = f"dim{i:02d}."
                state = {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
                if not entry.get("learned"):
                    continue
                if not state:
                    raise ModelFileError(f"{model_dir}/{MODEL_NPZ}: no arrays for dimension {entry.get('name')}")
                model = cls_.from_state(ms._params(i), state)
                expected = len(ms.input_index[i])
                if model.n_features_in_ != expected:
                    raise ModelFileError(f"{model_dir}: dimension {entry.get('name')} has {model.n_features_in_} "
                                         f"inputs, expected {expected}")
                ms.models_[i] = model
        except KeyError as err:
            raise ModelFileError(f"{model_dir}: missing {err}") from None
        except LearnerError as err:
            raise ModelFileError(f"{model_dir}: {err}") from None
        except (AttributeError, TypeError, ValueError) as err:
            raise ModelFileError(f"{model_dir}: malformed model description ({err})") from None
        ms.training_ = dict(meta.get("training") or {})
        return ms


def read_metadata(model_dir: str) -> dict[str, Any]:
    """model.json of a model directory, with its format version and learner checked."""
    path = os.path.join(model_dir, MODEL_JSON)
    if not os.path.isdir(model_dir):
        raise ModelFileError(f"model directory not found: {model_dir}")
    try:
        with open(path, encoding="utf-8") as f:
            meta = json.load(f)
    except FileNotFoundError:
        raise ModelFileError(f"{path} not found (not a model directory, or a save was interrupted)") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ModelFileError(f"{path} is not valid JSON (truncated or corrupt: {err})") from None
    if not isinstance(meta, dict):
        raise ModelFileError(f"{path} is not a CIML model description")
    version = meta.get("format_version")
    if version != FORMAT_VERSION:
        raise ModelFileError(f"{path} has format_version {version!r}; this CIML reads version {FORMAT_VERSION}")
    if meta.get("kind") != KIND:
        raise ModelFileError(f"{path} is not a CIML model set (kind {meta.get('kind')!r})")
    if meta.get("learner") not in KERNELS:
        raise ModelFileError(f"{path} names unknown learner {meta.get('learner')!r}; valid: {sorted(KERNELS)}")
    return meta


def _read_npz_bytes(model_dir: str, meta: dict[str, Any]) -> bytes:
    path = os.path.join(model_dir, MODEL_NPZ)
    try:
        with open(path, "rb") as f:
            data = f.read()
    except FileNotFoundError:
        raise ModelFileError(f"{path} not found") from None
    info = meta.get("npz") or {}
    if not isinstance(info, dict) or "sha256" not in info:
        raise ModelFileError(f"{model_dir}/{MODEL_JSON} has no npz checksum")
    if len(data) != info.get("bytes") or hashlib.sha256(data).hexdigest() != info["sha256"]:
        raise ModelFileError(f"{path} does not match the checksum in {MODEL_JSON} (truncated, modified, or "
                             f"written by a concurrent save: reload after the next /model_update)")
    return data


# ---------------------------------------------------------------------- ε at a reference
class EpsilonFunction:
    """ε(q, q̇, q̈) = J'(q)ᵀ Φ̃'(x) − Sᵀ Γ(x), eq. (17), from a model set.

    Callable with a reference point (anything with .q, .v, .a — e.g.
    ciml_control.references.ReferencePoint): returns ε (nv,) [N, Nm] at the reference,
    the generalized force the controller adds to M q̈ + h. Never returns NaN: a
    non-finite input or prediction gives zeros (the nominal model) and is counted in
    n_nonfinite. Holds its own Pinocchio data (not thread-safe).
    """

    def __init__(self, robot, model_set: ModelSet) -> None:
        from .dynamics import RigidBodyDynamics, selection_matrix

        model_set.check_robot(robot)
        self.robot = robot
        self.model_set = model_set
        self._dyn = RigidBodyDynamics(robot)
        self._S = selection_matrix(robot)
        self.n_nonfinite = 0

    def epsilon(self, q: np.ndarray, v: np.ndarray, a: np.ndarray, return_var: bool = False):
        """ε (nv,) at state (q, q̇, q̈); with return_var, also its variance per entry (nv,),
        from the predicted variances assuming independent dimensions."""
        from .extraction import learning_inputs
        from .projection import contact_invariant_basis

        nv = self.robot.nv
        q, v, a = (np.asarray(z, dtype=float) for z in (q, v, a))
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v)) and np.all(np.isfinite(a))):
            self.n_nonfinite += 1
            return (np.zeros(nv), np.zeros(nv)) if return_var else np.zeros(nv)
        x = learning_inputs(q, v, a)[0]
        phi, phi_var, gamma, gamma_var = self.model_set.predict_one(x)
        basis = contact_invariant_basis(self._dyn.foot_jacobians(q), self.robot.leg_joints)
        eps = basis.T @ phi - self._S.T @ gamma
        var = (basis.T ** 2) @ phi_var + (self._S.T ** 2) @ gamma_var
        if not (np.all(np.isfinite(eps)) and np.all(np.isfinite(var))):
            self.n_nonfinite += 1
            eps, var = np.zeros(nv), np.zeros(nv)
        return (eps, var) if return_var else eps

    def __call__(self, ref) -> np.ndarray:
        return self.epsilon(ref.q, ref.v, ref.a)


def load_epsilon_function(robot, model_dir: str) -> Callable[[Any], np.ndarray]:
    """epsilon_fn(ref) → ε (nv,) at ref.q, ref.v, ref.a from a trained model directory
    (for `ciml closed-loop --model MODEL_DIR` and ciml_sim.recorder.run_headless)."""
    return EpsilonFunction(robot, ModelSet.load(model_dir, robot))
