"""What every effect type declares (docs/ARCHITECTURE.md §5): one module per type, found by name.

An effect type carries its scenario fields (names, units, the range the simulator accepts), its
physical bounds and null value, the identification's candidate columns and the θ ↔ physical
conversion, its report wording and its MuJoCo form. Types outside the diagnosis' catalogue
(probes for "unexplained") declare fields and wording only.

θ are the candidate's linear parameters (diagnosis/candidates.py); "physical" parameters are the
scenario's (e.g. {"value": 5.8} [Nm]). Bounds (docs/DIAGNOSIS.md): a parameter outside them is not
a property of a robot; an estimate on a bound other than the null value is "not identified".
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, NamedTuple

import numpy as np

# --- bounds shared by several types (each type's own bounds live in its module) -------------------
MAX_ANGLE = math.radians(5.0)
"""[rad] largest encoder offset and IMU tilt (a few degrees: more is a mounting error one sees)."""
FRICTION_FRACTION = 0.5
"""Joint friction (Coulomb [Nm], viscous [Nm at 1 rad/s]) is at most this fraction of the torque limit."""
TORQUE_GAIN = (0.5, 2.0)
"""Range of an actuator's or torque sensor's gain."""
OFFSET_FRACTION = 0.2
"""A torque offset is at most this fraction of the torque limit."""
FALLBACK_TORQUE_LIMIT = 1000.0
"""[Nm] torque limit of a joint whose URDF gives none (0 or not finite)."""
COULOMB_SMOOTHING = 0.01
"""Velocity [rad/s] of the tanh that smooths sign(q̇) in the joint-friction regressors: a sticking
friction is fully developed as soon as the joint slides, and samples slower than
diagnosis/shrink.V_STICK (0.05) are projected out where it sticks, so the tanh is 1 above it
(tanh(5)). 0.03 left the regressor 7 % short at 0.05 rad/s, where a Stribeck curve is highest: a
0.1 rad/s Stribeck velocity came out 0.082 [0.064, 0.0998] with the breakaway 27 % high (gap-bench
case 19); with 0.01, 0.093 [0.073, 0.112] and 12.2 Nm for 12."""


def torque_limits(robot) -> np.ndarray:
    lim = np.asarray(robot.torque_limits, float)
    return np.where(np.isfinite(lim) & (lim > 0), lim, FALLBACK_TORQUE_LIMIT)


def joint_torque_limit(robot, joint: str | None) -> float:
    """τ_max of a joint (the largest of the robot's without one)."""
    lim = torque_limits(robot)
    return float(lim[robot.joint_names.index(joint)]) if joint is not None else float(np.max(lim))


def gain_theta(g: tuple[float, float]) -> tuple[float, float]:
    """θ = 1 − 1/g range of a gain range."""
    return 1.0 - 1.0 / g[0], 1.0 - 1.0 / g[1]


@dataclass(frozen=True)
class Field:
    """A scenario field: kind "joints" (a name, a list of names or "all"), "link", "float" or "vec3";
    unit; the range [lo, hi] the simulator accepts (each component of a vec3)."""

    kind: str
    unit: str = ""
    lo: float = -math.inf
    hi: float = math.inf


@dataclass(frozen=True)
class Candidate:
    """One candidate effect at one location, with its linear parameters θ.

    features: indices into the FeatureLayout; `layout.matrix(cand)` gives A (n_features × n_params)
    such that the candidate's prediction is features · A θ. group: candidates of one group exclude
    each other in a model (one nests the other, e.g. Stribeck and Coulomb friction of a joint).
    """

    type: str
    kind: str  # "rbd" | "actuation" | "sensor"
    param_names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    features: tuple[int, ...]
    joint: str | None = None
    joints: tuple[str, ...] = ()
    link: str | None = None
    in_catalogue: bool = True  # False for the out-of-catalogue probes
    group: str | None = None

    @property
    def label(self) -> str:
        where = self.link or self.joint or ("all" if len(self.joints) > 1 else "base")
        return f"{self.type}:{where}"

    @property
    def n_params(self) -> int:
        return len(self.param_names)

    def location(self) -> dict:
        if self.link is not None:
            return {"link": self.link}
        if self.joint is not None:
            return {"joint": self.joint}
        if self.joints:
            return {"joints": "all"}
        return {}


@dataclass
class Conversion:
    """What converting one candidate's θ needs besides θ: the identified gains of its joint (the
    actuation parameters of a joint convert together: a = 1 − 1/g, b = o/g, c = T/g), the fitted
    non-linear parameter of the candidate (Stribeck velocity) and the lag's reading of the logs."""

    gain: dict[str, float] = field(default_factory=dict)          # torque_gain per joint
    sensor_gain: dict[str, float] = field(default_factory=dict)   # torque_sensor_gain per joint
    nonlinear: dict[str, float] = field(default_factory=dict)     # candidate label → value
    lag_time_constant: Callable[[float, str | None], float] | None = None  # c → T (identification)


class Refinement(NamedTuple):
    """The bilinear parts of a fitted model (identification.fit_model) that its matrix A depends on."""

    payload_com: np.ndarray | None = None          # the payload's CoM: its point-mass rotational inertia
    lag_scale: dict[str, float] | None = None      # 1/g_j of the all-joint lag's column per joint
    nonlinear: dict[str, float] | None = None      # candidate label → its non-linear parameter


class EffectType:
    """Base of the effect modules: class attributes describe the type, methods convert.

    kind: "rbd" (acts on the rigid body: Φ̃), "actuation" (between command and torque sensor: Γ),
    "sensor" (the torque reading: Φ̃ and Γ); measurement_only: exerts no force (sensors);
    in_catalogue: the diagnosis has a candidate for it.
    """

    name: ClassVar[str]
    fields: ClassVar[dict[str, Field]]
    kind: ClassVar[str] = "rbd"
    measurement_only: ClassVar[bool] = False
    in_catalogue: ClassVar[bool] = True
    null: ClassVar[dict[str, Any]] = {}
    """Physical parameters of "no effect"."""
    wording: ClassVar[str] = ""
    """One sentence for the report: what the effect is physically."""
    mujoco: ClassVar[str | None] = None
    """MuJoCo's element for it (ciml export-mjcf); None: not exportable (say why in `mujoco_note`)."""
    mujoco_note: ClassVar[str] = ""
    nonlinear: ClassVar[tuple[str, float, float] | None] = None
    """(name, lo, hi) of a parameter the candidate is not linear in, fitted by a 1-D search."""
    speed_bins: ClassVar[bool] = False
    """Its parameter must agree across sliding-speed bins (identification.consistency: a friction level
    that changes with speed, like Stribeck friction, is not Coulomb friction)."""
    may_vanish: ClassVar[tuple[str, ...]] = ()
    """θ names that may rest at their null bound (0) while the effect is there (the main one may not)."""
    joint_feature_count: ClassVar[int] = 0
    """Per-joint joint-torque feature columns this type adds to the layout (joint_features)."""
    refined_by: ClassVar[str | None] = None
    """The Refinement field its `matrix` reads (None: a candidate's A is fixed, and the layout keeps it)."""

    # --- scenario side -----------------------------------------------------------------------
    def check(self, params: dict) -> str | None:
        """A scenario's fields that contradict each other (one line), or None."""
        return None

    # --- identification side -----------------------------------------------------------------
    def theta_bounds(self, robot, joint: str | None) -> tuple[tuple[float, ...], tuple[float, ...]]:
        raise NotImplementedError(self.name)

    def physical_range(self, robot) -> dict:
        raise NotImplementedError(self.name)

    def physical_violation(self, params: dict) -> str | None:
        """Which physical parameter leaves its range after the conversion from θ (None: all inside)."""
        return None

    def candidates(self, layout) -> list[tuple[tuple, Candidate]]:
        """(order key, candidate) of every location on this robot; the key orders the catalogue."""
        return []

    def matrix(self, layout, cand: Candidate, A: np.ndarray, refinement: Refinement) -> None:
        """Fill A (n_features × n_params): default one column per parameter over its features, or one
        parameter over all of them."""
        if cand.n_params == len(cand.features):
            for k, f in enumerate(cand.features):
                A[f, k] = 1.0
        else:
            A[list(cand.features), 0] = 1.0

    def to_physical(self, theta: np.ndarray, cand: Candidate, conv: Conversion) -> dict:
        raise NotImplementedError(self.name)

    def to_theta(self, params: dict, cand: Candidate, conv: Conversion) -> np.ndarray:
        """θ of physical parameters (the inverse of to_physical); ValueError for an invalid value."""
        raise NotImplementedError(self.name)

    def feature_theta(self, layout, cand: Candidate, params: dict, conv: Conversion) -> np.ndarray:
        """Coefficients on the feature columns of physical parameters (A θ)."""
        return layout.matrix(cand, nonlinear=conv.nonlinear) @ self.to_theta(params, cand, conv)

    def stiction(self, params: dict) -> float | None:
        """[Nm] the largest torque this friction holds a joint at rest with (its law is set-valued there:
        diagnosis/shrink.py), or None for an effect that does not stick."""
        return None

    def joint_features(self, v_joints: np.ndarray) -> np.ndarray:
        """(N × n_j × joint_feature_count) joint torques per unit parameter at joint velocities q̇,
        before the log's low-pass (diagnosis/candidates.effect_joint_regressors applies it)."""
        raise NotImplementedError(self.name)

    # --- MuJoCo side (ciml export-mjcf) ------------------------------------------------------
    def patch_mjcf(self, patch, effect: dict) -> None:
        """Apply one identified effect to the user's MJCF (ciml_learning.effects.mjcf.MjcfPatch)."""
        raise NotImplementedError(self.name)
