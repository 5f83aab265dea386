"""The per-dimension model set of the model error.

A ModelSet holds one independent learner per output dimension (paper §III-D):

- 18 rigid-body models of the generalized model error Φ̃ = J'ᵀΦ̃' (eq. 8; names
  rbd_output_names): the base wrench w (6), then each leg joint's rigid-body error e_j (12);
- 12 actuation models of Γ = τ − u (eq. 14), one per joint (robot.joint_names), from the
  joint's q, q̇, q̈ and its torque τ and rate τ̇.

Combined, they give the model error the controller adds (eq. 17):

    ε(q, q̇, q̈) = J'ᵀ Φ̃'(x) − Sᵀ Γ(x, τ, τ̇) = [w; e] − Sᵀ Γ

Why Γ from the torque (docs/ARCHITECTURE.md §1 names q_i, q̇_i, q̈_i only): an actuator's lag and gain
are functions of the torque it delivers and its rate, Γ ≈ −T τ̇ + (g − 1) τ, not of the
joint's state; at a reference the torque is the one it asks for, τ_ref and τ̇_ref of
dynamics.ReferenceTorque (EpsilonFunction).

Why the generalized coordinates, not the contact-invariant ones of eq. (11): J' puts a leg's
joint-space error into the base entries of Φ̃' as −J_i,baseᵀ B_i⁻ᵀ e_i (projection.leg_coupling),
and a stance leg's e_i is not observed, so the base entries of Φ̃' are a function of every
leg's state and of the gait — a model of them learns the gaits it was trained on. Each leg
joint's error e_j = (J'ᵀΦ̃')_j is observed while its leg swings and learned from that joint's
own q, q̇, q̈ (a friction, a link-mass error of the leg). The base wrench is learned after the
legs, from the base's own state (roll, pitch, q̇_base, q̈_base: a payload's weight and
inertia) and every joint's velocity q̇: its target w = (J'ᵀΦ̃')_base + Σ_stance C_j ê_j adds
back the stance legs' joint errors with the learned leg models ê (the swing legs' are in
J'ᵀΦ̃' already), and what the leg models miss of a stance joint's error reaches the base
through the contact, mostly as a function of that joint's velocity (joint friction: the
leg models learn it in swing, at other positions and accelerations).

The measurements behind these choices (feedback effort with and without each) and the
earlier formats they replaced: results/MODEL_HISTORY.md.

Observed mask: the base rows are observed in every valid sample, a leg joint's row while its
leg swings (extraction.ExtractionResult.generalized_observed); each model learns only from
valid samples where its row is observed. The actuation models learn from every sample whose
torques are usable (`effort_valid`: valid, and near contact changes too: Γ = τ − u does not see
the contacts, and a trot's largest torque rates are there; filters.contact_change_mask).
A dimension with no usable sample keeps no model: it predicts zero (the nominal model) with
its prior variance, as every learner does away from its data.

Standardisation happens inside the set: inputs are centred and scaled per column
(input_mean_, input_scale_), outputs only scaled (output_scale_, their RMS), never
shifted — zero stays "no error", so the learners' zero-mean fallback is the nominal
model. Learners see standardised data; predictions are returned in SI units
(N, Nm; variances in N², Nm²).

API (X: N × 74 learning inputs, extraction.learning_inputs: eq. 12, τ, τ̇; rbd: Φ̃ (N × 18)
and its mask; C: leg coupling (N × 6 × n_j); Γ (N × n_j)):

    ms = ModelSet.for_robot(robot, "lwpr")            # empty set, default scaling
    ms.fit(X, rbd, rbd_observed, Gamma, valid, C)     # offline: legs and actuators, then the base
    ms.calibrate(X, rbd, rbd_observed, Gamma, valid)  # online: optional, before learning
    ms.partial_fit_one(x, rbd, observed, gamma, C)    # one sample, legs before the base
    ms.partial_fit(X, rbd, rbd_observed, Gamma, valid, C)   # = partial_fit_one on each, in order
    rbd, rbd_var, act, act_var = ms.predict_one(x)   # fast single-sample prediction
    eps = EpsilonFunction(robot, ms); eps(ref)       # ε at a reference point, eq. (17) (model_epsilon)
    ms.save(model_dir)                               # atomic snapshot (npz + json)
    ms = ModelSet.load(model_dir, robot)             # validated, refuses bad files

partial_fit needs an incremental learner (LWPR); the sparse GP is batch-only (fit).
A ModelSet is not thread-safe: the online learner should save a snapshot from its own
thread and then announce it (/model_update); the server loads it after the announcement.

Files: ms.save / ModelSet.load write and read the format of ciml_learning.learning.model_files
(npz + JSON, versioned, checksummed as a whole); ε at a reference: ciml_learning.learning.model_epsilon.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ciml_learning.core.errors import CimlError
from ciml_learning.core.physical_bounds import N_BASE
from ciml_learning.learning.learners import LWPR, Learner, LearnerError, LWPRStack, learner_class
from ciml_learning.learning.model_files import (
    KERNELS,
    MODEL_JSON,
    MODEL_NPZ,
    ModelFileError,
    read_arrays,
    read_metadata,
    write_model_dir,
)
from ciml_learning.learning.parallel import fit_dimensions

DEFAULT_PARAMS: dict[str, dict[str, dict[str, Any]]] = {
    # Hyper-parameters per learner and group, in standardised units (unit-variance inputs,
    # unit-RMS outputs). Groups: "base" the base wrench (26 inputs: the base state's 14 and the
    # 12 joint velocities), "leg" a leg joint's rigid-body error (3 inputs) and "actuation" (5
    # inputs). LWPR: the base's inputs lie near the low-dimensional cycles of the gaits — a
    # diagonal metric, at most 3 PLS projections and narrow initial fields (D = 0.2) put a few
    # tens of fields along a cycle; a joint's 3 inputs: a diagonal metric with D = 0.8 for the
    # rigid-body error (generalised best to new gaits among 0.2–2 in closed loop) and a metric
    # penalty γ = 1e-3 that keeps its fields from narrowing: learned online from ten minutes of
    # one trot, with γ = 1e-6 the fields narrow on the swing states the robot reaches and
    # extrapolate ever worse to the references the controller asks at (the live fade); with 1e-3
    # they hold, offline fits unchanged (1e-2 holds too but costs offline fits; results/
    # live_online_learning/go1_reference_eps/leg_penalty_output.txt); a full metric for the
    # actuation error. Offline fit() visits the samples in random order (shuffle; LWPR
    # assumes no ordering, and time-ordered gait data otherwise drift the fields); online
    # partial_fit() takes them as they come. The sparse GP fits its hyper-parameters on 1,500
    # random samples per dimension (learners/sgpr.py explains why), the rigid-body ones with 150
    # of their 250 inducing inputs (the posterior uses all 250): 0.4 × the fit's time, the same
    # held-out error and closed-loop effort (results/scaling/README.md, "SGPR training").
    "lwpr": {
        "base": {"init_D": 0.2, "diag_only": True, "init_alpha": 10.0, "w_gen": 0.1, "w_prune": 0.95,
                 "max_projections": 3, "penalty": 1e-6, "max_rfs": 1500, "n_epochs": 1, "shuffle": True},
        "leg": {"init_D": 0.8, "diag_only": True, "init_alpha": 10.0, "w_gen": 0.1, "w_prune": 0.95,
                "max_projections": 3, "penalty": 1e-3, "max_rfs": 1500, "n_epochs": 1, "shuffle": True},
        "actuation": {"init_D": 10.0, "diag_only": False, "init_alpha": 50.0, "w_gen": 0.2, "w_prune": 0.95,
                      "penalty": 1e-6, "max_rfs": 400, "n_epochs": 2, "shuffle": True},
    },
    "sgpr": {
        "base": {"n_inducing": 250, "hyper_inducing": 150, "n_hyper_samples": 1500, "max_iters": 80},
        "leg": {"n_inducing": 250, "hyper_inducing": 150, "n_hyper_samples": 1500, "max_iters": 80},
        "actuation": {"n_inducing": 100, "n_hyper_samples": 1500, "max_iters": 100},
    },
}
"""Default hyper-parameters (paper: 250 inducing inputs per RBD and 100 per actuation
dimension). Override per group with ModelSet(..., params={"base": {...}, "leg": {...},
"actuation": {...}})."""
GROUPS = ("base", "leg", "actuation")

MIN_SAMPLES = 10
"""A dimension with fewer usable samples than this keeps no model (zero error)."""


class ModelSetError(CimlError):
    """Bad input to a model set (shapes, learner without partial_fit, ...)."""


@dataclass
class Prediction:
    """Predicted errors (SI units) and their variances, one row per input."""

    rbd: np.ndarray            # N × 18, Φ̃ = [w; e] [N, Nm]
    rbd_var: np.ndarray        # N × 18 [N², Nm²]
    actuation: np.ndarray      # N × n_j, Γ [Nm]
    actuation_var: np.ndarray  # N × n_j [Nm²]


def joint_state_names(joint: str) -> tuple[str, str, str]:
    """Names of a joint's state among the learning inputs (q_i, q̇_i, q̈_i)."""
    return (f"q_{joint}", f"qd_{joint}", f"qdd_{joint}")


def actuation_input_names(joint: str) -> tuple[str, ...]:
    """Names of joint i's actuation-model inputs: (q_i, q̇_i, q̈_i, τ_i, τ̇_i)."""
    return joint_state_names(joint) + (f"tau_{joint}", f"taud_{joint}")


def rbd_output_names(robot) -> tuple[str, ...]:
    """Names of the rigid-body outputs: the base wrench (as in robot.rbd_error_names), then
    "rbd_<joint>" for each joint's rigid-body error (rows of Φ̃ = J'ᵀΦ̃')."""
    return tuple(robot.rbd_error_names[:N_BASE]) + tuple(f"rbd_{j}" for j in robot.joint_names)


def rbd_input_names(robot) -> dict[str, tuple[str, ...]]:
    """Inputs of each rigid-body model (module docstring): the base's state (roll, pitch,
    q̇_base, q̈_base) and every joint's q̇ for the base wrench, the joint's own q, q̇, q̈ for a
    leg joint's error."""
    from ciml_learning.core.extraction import learning_input_names

    names = learning_input_names(robot)
    base_state = ("base_roll", "base_pitch") + tuple(
        f"{kind}_{d}" for kind in ("qd", "qdd") for d in robot.dof_names[:N_BASE])
    base_state += tuple(joint_state_names(j)[1] for j in robot.joint_names)
    base_state = tuple(sorted(base_state, key=names.index))
    rbd = rbd_output_names(robot)
    out = {d: base_state for d in rbd[:N_BASE]}
    for d, joint in zip(rbd[N_BASE:], robot.joint_names):
        out[d] = joint_state_names(joint)
    return out


def default_scaling(robot) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Input mean/scale and output scales for a set that learns online from scratch.

    Derived from the robot description only (no data): joints centred on the standing
    posture with a sixth of their range as scale, roll/pitch 0.1 rad, velocities 0.5 m/s,
    0.5 rad/s (base) and 2 rad/s (joints), accelerations 5 m/s², 5 rad/s², 30 rad/s²,
    torques a quarter of the limit, torque rates 10 × the limit per second;
    outputs 5 % of the robot's weight (base forces), 5 % of weight × 0.1 m (base torques)
    and 5 % of each joint's torque limit (its rigid-body and its actuation error).
    calibrate() on real data replaces these.
    """
    from ciml_learning.core.extraction import learning_input_names

    names = learning_input_names(robot)
    mean = np.zeros(len(names))
    scale = np.ones(len(names))
    lo, hi = robot.position_limits
    span = np.where(np.isfinite(hi - lo) & (hi - lo > 0), hi - lo, 2.0)
    index = {n: i for i, n in enumerate(names)}
    scale[index["base_roll"]] = scale[index["base_pitch"]] = 0.1
    for j, joint in enumerate(robot.joint_names):
        q, qd, qdd, tau, taud = (index[n] for n in actuation_input_names(joint))
        mean[q] = robot.standing_joints[j]
        scale[q] = span[j] / 6.0
        scale[qd] = 2.0
        scale[qdd] = 30.0
        limit = robot.torque_limits[j] if robot.torque_limits[j] > 0 else 100.0
        scale[tau] = 0.25 * limit
        scale[taud] = 10.0 * limit
    for k, dof in enumerate(robot.dof_names[:6]):
        scale[index[f"qd_{dof}"]] = 0.5
        scale[index[f"qdd_{dof}"]] = 5.0
    weight = robot.total_mass * 9.81
    joints = 0.05 * np.where(robot.torque_limits > 0, robot.torque_limits, 100.0)
    out = np.concatenate([np.full(3, 0.05 * weight), np.full(3, 0.05 * weight * 0.1), joints, joints])
    return mean, scale, out


class ModelSet:
    """18 rigid-body + n_j actuation models of the model error (module docstring).

    Attributes (after construction): learner, input_names, rbd_names, joint_names,
    foot_frames, params (group → hyper-parameters), rbd_inputs (rbd name → its input
    names; default all), input_index (per output dimension, its columns of x).
    Learned/calibrated state: input_mean_, input_scale_, output_scale_ (18 + n_j),
    models_ (list of Learner or None, RBD dimensions first), n_samples_ (per dimension),
    training_ (dict of provenance written to model.json).
    """

    def __init__(self, learner: str, input_names, rbd_names, joint_names, foot_frames,
                 params: dict | None = None, rbd_inputs: dict | None = None) -> None:
        self.learner = learner
        cls = learner_class(learner)
        self.input_names = tuple(input_names)
        self.rbd_names = tuple(rbd_names)
        self.joint_names = tuple(joint_names)
        self.foot_frames = tuple(foot_frames)
        unknown = set(params or {}) - set(GROUPS)
        if unknown:
            raise ModelSetError(f"unknown parameter groups {sorted(unknown)}; valid: {list(GROUPS)}")
        self.params = {g: {**DEFAULT_PARAMS[learner][g], **(params or {}).get(g, {})} for g in GROUPS}
        for p in self.params.values():
            cls.from_params(p)  # validates names and values now, not after an hour of training
        if len(self.rbd_names) != N_BASE + len(self.joint_names):
            raise ModelSetError(f"{len(self.rbd_names)} rigid-body outputs, expected the base's {N_BASE} "
                                f"and one per joint ({len(self.joint_names)})")
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
        self._stacks: tuple[tuple, dict[str, LWPRStack]] | None = None

    def __getstate__(self) -> dict[str, Any]:
        """Copies and pickles leave the LWPR stacks behind (the copy's models own their arrays)."""
        return {**self.__dict__, "_stacks": None}

    @classmethod
    def for_robot(cls, robot, learner: str, params: dict | None = None) -> "ModelSet":
        """An empty set for a robot, with default_scaling(robot) until calibrated."""
        from ciml_learning.core.extraction import learning_input_names

        ms = cls(learner, learning_input_names(robot), rbd_output_names(robot), robot.joint_names,
                 robot.foot_frames, params, rbd_input_names(robot))
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

    def group(self, i: int) -> str:
        """Hyper-parameter group of output dimension i: "base", "leg" or "actuation"."""
        return "base" if i < N_BASE else "leg" if i < self.n_rbd else "actuation"

    def group_dims(self, group: str) -> range:
        """The output dimensions of a hyper-parameter group (contiguous)."""
        return {"base": range(N_BASE), "leg": range(N_BASE, self.n_rbd),
                "actuation": range(self.n_rbd, self.n_outputs)}[group]

    def lwpr_stacks(self) -> dict[str, LWPRStack]:
        """The groups whose dimensions all hold an LWPR model, stacked (LWPRStack): the online path
        updates and predicts a group in one kernel call. Rebuilt when a model was replaced or left
        its stack; empty for other learners."""
        models = tuple(self.models_)
        cached = getattr(self, "_stacks", None)
        if cached is not None and cached[0] == models and all(st.intact for st in cached[1].values()):
            return cached[1]
        stacks = {}
        for group in GROUPS:
            dims = self.group_dims(group)
            members = [m for m in (models[i] for i in dims) if isinstance(m, LWPR) and m.is_fitted]
            if len(members) == len(dims):
                stacks[group] = LWPRStack(members, [self.input_index[i] for i in dims])
        self._stacks = (models, stacks)
        return stacks

    def is_fitted(self) -> bool:
        return any(m is not None for m in self.models_)

    def new_learner(self, i: int) -> Learner:
        """A fresh learner for output dimension i with its group's hyper-parameters."""
        return learner_class(self.learner).from_params(self.params[self.group(i)])

    # ------------------------------------------------------------------ data handling
    def _check_data(self, X, rbd_error, rbd_observed, actuation_error, valid, leg_coupling=None, effort_valid=None):
        """Arrays checked and typed. With effort_valid (N,), the rows whose Γ is usable
        (extraction.ExtractionResult.effort_valid), the two masks become one set of rows: valid
        = either, a rigid-body row observed only where it was valid, Γ NaN where not usable."""
        X = np.asarray(X, dtype=float)
        n = len(X)
        rbd_error = np.asarray(rbd_error, dtype=float)
        rbd_observed = np.asarray(rbd_observed, dtype=bool)
        actuation_error = np.asarray(actuation_error, dtype=float)
        valid = np.ones(n, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
        C = np.zeros((n, N_BASE, self.n_actuation)) if leg_coupling is None else np.asarray(leg_coupling, float)
        shapes = {"X": (X.shape, (n, len(self.input_names))), "rbd_error": (rbd_error.shape, (n, self.n_rbd)),
                  "rbd_observed": (rbd_observed.shape, (n, self.n_rbd)),
                  "actuation_error": (actuation_error.shape, (n, self.n_actuation)), "valid": (valid.shape, (n,)),
                  "leg_coupling": (C.shape, (n, N_BASE, self.n_actuation))}
        bad = {k: v[0] for k, v in shapes.items() if v[0] != v[1]}
        if bad:
            raise ModelSetError(f"data shapes {bad} do not match {len(self.input_names)} inputs, "
                                f"{self.n_rbd} RBD and {self.n_actuation} actuation outputs")
        if effort_valid is not None:
            effort_valid = np.asarray(effort_valid, dtype=bool)
            if effort_valid.shape != valid.shape:
                raise ModelSetError(f"effort_valid has shape {effort_valid.shape}, not {valid.shape}")
            rbd_observed = rbd_observed & valid[:, None]
            actuation_error = np.where(effort_valid[:, None], actuation_error, np.nan)
            valid = valid | effort_valid
        valid = valid & np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(C), axis=(1, 2))
        return X, rbd_error, rbd_observed, actuation_error, valid, C

    def _usable_rows(self, i: int, rbd_error, rbd_observed, actuation_error, valid) -> np.ndarray:
        if i < self.n_rbd:
            return valid & rbd_observed[:, i] & np.isfinite(rbd_error[:, i])
        return valid & np.isfinite(actuation_error[:, i - self.n_rbd])

    def calibrate(self, X, rbd_error, rbd_observed, actuation_error, valid=None, effort_valid=None) -> "ModelSet":
        """Set the input mean/scale and output scales from data (before any learning)."""
        if self.is_fitted():
            raise ModelSetError("calibrate() must come before learning: the models use the old scaling")
        X, rbd_error, rbd_observed, actuation_error, valid, _ = self._check_data(
            X, rbd_error, rbd_observed, actuation_error, valid, effort_valid=effort_valid)
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

    def base_wrench_targets(self, Xs: np.ndarray, rbd_error: np.ndarray, rbd_observed: np.ndarray,
                            leg_coupling: np.ndarray) -> np.ndarray:
        """w = (J'ᵀΦ̃')_base + Σ_j C_j ê_j over the unobserved (stance) leg joints j, with ê the
        leg models' predictions at the standardised inputs Xs (module docstring)."""
        stance = ~rbd_observed[:, N_BASE:]
        e_hat = np.zeros(stance.shape)
        legs = self.lwpr_stacks().get("leg") if len(Xs) == 1 else None
        if legs is not None:  # online, one sample per tick: the stacked leg models, one call
            mean, _ = legs.predict(Xs[0], stance[0])
            e_hat[0] = mean * self.output_scale_[N_BASE:self.n_rbd]
        else:
            for j in range(self.n_actuation):
                model, rows = self.models_[N_BASE + j], stance[:, j]
                if model is None or not rows.any():
                    continue
                if len(Xs) == 1:  # online without a stack: the one-sample path (the same numbers)
                    e_hat[0, j] = (model.predict_one(self._dim_inputs(N_BASE + j, Xs[0]))[0]
                                   * self.output_scale_[N_BASE + j])
                else:
                    e_hat[rows, j] = (model.predict(self._dim_inputs(N_BASE + j, Xs[rows]))
                                      * self.output_scale_[N_BASE + j])
        return rbd_error[:, :N_BASE] + np.einsum("nbj,nj->nb", leg_coupling, e_hat)

    # ------------------------------------------------------------------ learning
    def fit(self, X, rbd_error, rbd_observed, actuation_error, valid=None, leg_coupling=None, n_jobs: int = 1,
            progress: bool = False, calibrate: bool = True, effort_valid=None) -> "ModelSet":
        """Learn every dimension from scratch, in parallel (parallel.fit_dimensions): the leg
        joints and the actuators first, then the base wrench with the stance legs' learned
        errors added back (base_wrench_targets).

        X: learning inputs (N × 74, extraction.learning_inputs); rbd_error: Φ̃ = J'ᵀΦ̃' (N × 18,
        anything where unobserved); rbd_observed: (N × 18) bool; actuation_error: Γ (N × n_j);
        valid: (N,) bool; leg_coupling: C (N × 6 × n_j, projection.leg_coupling; None: no
        coupling); effort_valid: (N,) bool, the rows Γ learns from (None: valid). Returns self.
        """
        X, rbd_error, rbd_observed, actuation_error, valid, C = self._check_data(
            X, rbd_error, rbd_observed, actuation_error, valid, leg_coupling, effort_valid)
        self.models_ = [None] * self.n_outputs
        if calibrate:
            self.calibrate(X, rbd_error, rbd_observed, actuation_error, valid)
        Xs = self.standardize(X)
        targets = np.hstack([rbd_error, actuation_error])
        self.n_samples_ = np.zeros(self.n_outputs, dtype=np.int64)
        for stage in (range(N_BASE, self.n_outputs), range(N_BASE)):
            if stage.start == 0:
                b = valid & rbd_observed[:, :N_BASE].any(axis=1)
                targets[b, :N_BASE] = self.base_wrench_targets(Xs[b], rbd_error[b], rbd_observed[b], C[b])
            jobs = []
            for i in stage:
                rows = self._usable_rows(i, rbd_error, rbd_observed, actuation_error, valid)
                self.n_samples_[i] = int(rows.sum())
                if self.n_samples_[i] >= MIN_SAMPLES:
                    jobs.append((i, self._dim_inputs(i, Xs[rows]), targets[rows, i] / self.output_scale_[i]))
            fitted = fit_dimensions(self.learner, [self.params[self.group(i)] for i, _, _ in jobs], jobs,
                                    n_jobs=n_jobs, progress=progress, names=[self.output_names[i] for i, _, _ in jobs])
            for (i, _, _), model in zip(jobs, fitted):
                self.models_[i] = model
        return self

    def _require_incremental(self) -> None:
        if not learner_class(self.learner).supports_partial_fit:
            raise ModelSetError(f"learner {self.learner!r} has no partial_fit (batch only); use 'lwpr' online")

    def partial_fit(self, X, rbd_error, rbd_observed, actuation_error, valid=None, leg_coupling=None,
                    effort_valid=None) -> "ModelSet":
        """Incremental learning on a batch of samples in time order: partial_fit_one on each
        valid sample, in order (the base targets depend on the leg models at that time)."""
        self._require_incremental()
        X, rbd_error, rbd_observed, actuation_error, valid, C = self._check_data(
            X, rbd_error, rbd_observed, actuation_error, valid, leg_coupling, effort_valid)
        for k in np.flatnonzero(valid):
            self.partial_fit_one(X[k], rbd_error[k], rbd_observed[k], actuation_error[k], C[k])
        return self

    def partial_fit_one(self, x: np.ndarray, rbd_error: np.ndarray, rbd_observed: np.ndarray,
                        actuation_error: np.ndarray, leg_coupling: np.ndarray | None = None) -> None:
        """Learn from one valid sample (online, 250 Hz): x (74,), Φ̃ (18,), mask (18,), Γ (n_j,),
        C (6 × n_j; None: no coupling). The leg joints and actuators first, then the base.

        Non-finite values are skipped per dimension (never learned)."""
        self._require_incremental()
        x = np.asarray(x, dtype=float)
        if not np.all(np.isfinite(x)):
            return
        xs = (x - self.input_mean_) / self.input_scale_
        targets = np.concatenate([rbd_error, actuation_error])
        observed = np.concatenate([rbd_observed, np.ones(self.n_actuation, bool)])
        self._update_group("leg", xs, targets, observed)
        self._update_group("actuation", xs, targets, observed)
        if leg_coupling is not None and observed[:N_BASE].any():
            targets[:N_BASE] = self.base_wrench_targets(xs[None], targets[None, :self.n_rbd],
                                                        observed[None, :self.n_rbd], np.asarray(leg_coupling)[None])[0]
        self._update_group("base", xs, targets, observed)

    def _update_group(self, group: str, xs: np.ndarray, targets: np.ndarray, observed: np.ndarray) -> None:
        """One sample into a group's models: stacked in one call, else one model after the other
        (until every dimension of the group has its model)."""
        dims = self.group_dims(group)
        stack = self.lwpr_stacks().get(group)
        if stack is None:
            for i in dims:
                self._update_one(i, xs, targets[i], observed[i])
            return
        part = slice(dims.start, dims.stop)
        learn = observed[part] & np.isfinite(targets[part])
        stack.update(xs, targets[part] / self.output_scale_[part], learn)
        self.n_samples_[part] += learn

    def _update_one(self, i: int, xs: np.ndarray, y: float, observed: bool) -> None:
        if not observed or not np.isfinite(y):
            return
        model = self.models_[i]
        if model is None:
            model = self.models_[i] = self.new_learner(i)
        model.update(xs[self.input_index[i]], y / self.output_scale_[i])
        self.n_samples_[i] += 1

    # ------------------------------------------------------------------ prediction
    def predict(self, X: np.ndarray, return_var: bool = True) -> Prediction:
        """Φ̃ and Γ (and variances) at learning inputs X (N × 74 or 74,)."""
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
        """Fast single-sample prediction: (Φ̃ (18), var (18), Γ (n_j), var (n_j)), SI units.

        No input checks beyond the caller's (x must be finite, 74 entries)."""
        mean, var = self._predict_dims(self.standardize(x), range(self.n_outputs))
        n = self.n_rbd
        return mean[:n], var[:n], mean[n:], var[n:]

    def predict_part_one(self, x: np.ndarray, part: str) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance) of the "rbd" or the "actuation" dimensions at one input x: the
        rigid-body models do not read the torque inputs, so they can be predicted before τ is known."""
        dims = range(self.n_rbd) if part == "rbd" else range(self.n_rbd, self.n_outputs)
        return self._predict_dims(self.standardize(x), dims)

    def _predict_dims(self, xs: np.ndarray, dims: range) -> tuple[np.ndarray, np.ndarray]:
        """(mean, variance) of the dimensions `dims` (whole groups) at standardised inputs xs: a
        stacked group in one call, the others one model after the other."""
        mean = np.zeros(len(dims))
        var = np.empty(len(dims))
        stacks = self.lwpr_stacks()
        for group in GROUPS:
            part = self.group_dims(group)
            if part.start < dims.start or part.stop > dims.stop:
                continue
            out = slice(part.start - dims.start, part.stop - dims.start)
            s = self.output_scale_[part.start:part.stop]
            if group in stacks:
                m, sd = stacks[group].predict(xs)
                mean[out] = m * s
                var[out] = (sd * s) * (sd * s)
                continue
            for k, i in zip(range(out.start, out.stop), part):
                model = self.models_[i]
                if model is None:
                    var[k] = s[i - part.start] * s[i - part.start]
                    continue
                m1, sd1 = model.predict_one(xs[self.input_index[i]])
                mean[k] = m1 * s[i - part.start]
                v = sd1 * s[i - part.start]
                var[k] = v * v  # as the stacked path: v * v, not v ** 2 (libm's pow, 1 ulp off now and then)
        return mean, var

    # ------------------------------------------------------------------ files
    def check_robot(self, robot, where: str = "model") -> None:
        """Raise ModelFileError unless the set's names match the robot's."""
        from ciml_learning.core.extraction import learning_input_names

        for what, mine, theirs in (("joints", self.joint_names, tuple(robot.joint_names)),
                                   ("feet", self.foot_frames, tuple(robot.foot_frames)),
                                   ("RBD outputs", self.rbd_names, rbd_output_names(robot)),
                                   ("inputs", self.input_names, tuple(learning_input_names(robot)))):
            if mine != theirs:
                raise ModelFileError(f"{where} was trained for a different robot: {what} {list(mine)} "
                                     f"but the robot has {list(theirs)}")

    def description(self) -> dict[str, Any]:
        """The set's part of model.json (model_files.write_model_dir adds the format's)."""
        dims = []
        for i, model in enumerate(self.models_):
            entry = {"name": self.output_names[i], "kind": self.dimension_kind(i), "samples": int(self.n_samples_[i]),
                     "output_scale": float(self.output_scale_[i]), "learned": model is not None}
            if model is not None and hasattr(model, "summary"):
                entry["summary"] = model.summary()
            dims.append(entry)
        return {
            "learner": self.learner,
            "kernel": KERNELS[self.learner],
            "params": self.params,
            "inputs": {"names": list(self.input_names),
                       "rbd": {d: list(self.rbd_inputs[d]) for d in self.rbd_names},
                       "actuation": {j: list(actuation_input_names(j)) for j in self.joint_names}},
            "outputs": {"rbd": list(self.rbd_names), "actuation": list(self.joint_names),
                        "units": {"rbd": "N (base forces), Nm (base torques, joints)", "actuation": "Nm"},
                        "rbd_definition": "generalized rigid-body error J'^T Phi~' (eq. 8): base wrench, joints"},
            "robot": {"joint_names": list(self.joint_names), "foot_frames": list(self.foot_frames)},
            "training": self.training_,
            "dimensions": dims,
        }

    def to_arrays(self) -> dict[str, np.ndarray]:
        arrays = {"input_mean": self.input_mean_, "input_scale": self.input_scale_,
                  "output_scale": self.output_scale_, "n_samples": self.n_samples_}
        for i, model in enumerate(self.models_):
            if model is not None:
                for key, value in model.get_state().items():
                    arrays[f"dim{i:02d}.{key}"] = np.asarray(value)
        return arrays

    def save(self, model_dir: str, extra_files: dict[str, bytes] | None = None, what: str = "--out") -> dict[str, Any]:
        """Write model_dir (model.npz, model.json and `extra_files`) as one new directory that
        replaces the old one in one step (model_files.write_model_dir); returns the metadata."""
        return write_model_dir(model_dir, self.to_arrays(), self.description(), extra_files, what)

    @classmethod
    def load(cls, model_dir: str, robot=None) -> "ModelSet":
        """Read and validate a model directory; with `robot`, also check it was trained for it."""
        meta = read_metadata(model_dir)
        arrays = read_arrays(model_dir, meta)
        try:
            ms = cls(meta["learner"], meta["inputs"]["names"], meta["outputs"]["rbd"], meta["outputs"]["actuation"],
                     meta["robot"]["foot_frames"], meta["params"], meta["inputs"]["rbd"])
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
                model = cls_.from_state(ms.params[ms.group(i)], state)
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
        ms.lwpr_stacks()  # stacked now (~2 ms), not at a served model's first prediction
        return ms
