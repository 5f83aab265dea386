"""Candidate unmodelled effects (docs/ARCHITECTURE.md §5) as physically parameterised regressors.

Every candidate is linear (or linearised) in its parameters θ. A candidate of the rigid-body
kind predicts a generalized force e (nv) — the model error Φ̃ of eq. (3),
M q̈ + h + Φ̃ = Sᵀτ + J_cᵀλ, i.e. minus the force the effect exerts on the robot — which is
passed through the very eq. (11) operator as the measured error (extraction.observation_operators):
Φ̃'_pred = O e. A candidate of the actuation kind predicts the actuation error Γ = τ − u of
eq. (14) directly. Regressors are computed once per sample as *features* (one column each);
a candidate's columns are a fixed linear map A of the features (A is a selection, except
for the payload — whose rotational inertia depends on its CoM — and the all-joint lag).

Features (e-convention, per sample; q, q̇, q̈, τ, τ̇ are the filtered log):
    joint Coulomb friction j   e_{6+j} = LP(tanh(q̇_j / v_s))         θ = f_c ≥ 0 [Nm]
    joint viscous friction j   e_{6+j} = q̇_j                          θ = b ≥ 0 [Nm s/rad]
    encoder offset j           e = −∂(Mq̈+h)/∂q_j + ∂(J_cᵀλ)/∂q_j      θ = δ [rad]  (q_meas = q_true + δ)
    base IMU tilt              e = −∂(Mq̈+h)/∂θ_{roll,pitch}           θ = (roll, pitch) [rad]
                               (a body-frame rotation of the base: only gravity changes; the
                               contact term drops out exactly because P_c is rotation-invariant)
    joint Stribeck friction j  e_{6+j} = LP(tanh(q̇_j / v_s) exp(−(q̇_j / v_k)²)) for each v_k of its grid
                               (joint_feature0: columns an effect type declares, EffectType.joint_features)
    root inertial parameters   e = Y_root(q, q̇, q̈) Δπ_root             (payload: Δπ of a point mass)
    link mass scale l          e = Y_joint(l)(q, q̇, q̈) π_l            θ = s − 1
    joint torque j             e_{6+j} = 1   (no candidate: a unit torque error at joint j, for the
                               stiction of Coulomb friction)
    unmodelled joint torque j  e_{6+j} = f_j(q_j), a free-form torque (generic_joint_basis):
                               not an effect but the probe for effects outside the catalogue
                               (identification.py: it competes with the catalogue, and what it
                               explains is reported as unexplained, localised at joint j)

Command-update sampling (the baseline, part of every model, not an effect of the robot): a log
sampled at the controller tick reports the joint loop's torque under the command *before* the
new one takes effect; the torque acting around the tick is on average ½ Δu higher, with
Δu ≈ Δt (u̇ + K_p q̇ + K_d q̈) for a PD joint loop that tracks moving targets (Δt the tick).
So e_j = θ₁ q̇_j + θ₂ q̈_j + θ₃ u̇_j on every joint, with θ₃ ≈ −Δt/2, θ₁ ≈ −K_p Δt/2,
θ₂ ≈ −K_d Δt/2 — three numbers for the whole robot, fitted with every candidate set.
    actuation, joint j         Γ_j = a τ_j + b − c τ̇_j                 a = 1 − 1/g, b = o/g, c = T/g

Torque-sensor effects (the sensor, not the actuator): the measured τ_m = g_s τ + o_s while the
joint receives the true τ. The nominal model then sees Φ̃ = Sᵀ(τ_m − τ) on top of Γ, and both
are a_s τ_m + b_s at joint j (a_s = 1 − 1/g_s, b_s = o_s/g_s), one parameter set on both kinds
of rows — an actuator gain or offset shows in Γ only:
    torque sensor gain j       e_{6+j} = τ_m,j and Γ_j: τ_m,j          θ = a_s
    torque sensor offset j     e_{6+j} = 1 and Γ_j: 1                  θ = b_s
    unmodelled sensor torque j e_{6+j} = f_j(q_j) and Γ_j: f_j(q_j)   (the probe at sensor level:
                               a position-dependent torque reading error, e.g. a ripple)

Which features each effect type's candidates combine, their bounds and the θ ↔ physical
conversion: the type's module in ciml_learning/effects (the registry); this module holds the
feature columns and evaluates them.

The actuation line is exact for τ = g·ℓ + o, T ℓ̇ + ℓ = u (a first-order lag ℓ of the command,
then gain and offset): Γ = τ − u = (1 − 1/g)(τ − o) + o − (T/g) τ̇. λ in the encoder term is
the contact force estimated from the measured residual, λ̂ = −(J_cᵀ)⁺ r. Y is Pinocchio's
joint-torque regressor (pin.computeJointTorqueRegressor), ∂(Mq̈+h)/∂q from
pin.computeRNEADerivatives, ∂J/∂q_j from pin.computeJointJacobiansTimeVariation with q̇ = e_j.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from ciml_learning.core.filters import filter_offline, lowpass_taps
from ciml_learning.core.robot import RobotDescription
from ciml_learning.diagnosis.bounds import BASELINE, parameter_bounds
from ciml_learning.effects import CATALOGUE, EFFECTS, Candidate, Refinement, effect_type
from ciml_learning.effects.base import COULOMB_SMOOTHING
from ciml_learning.effects.payload import point_mass_rotational

__all__ = ["COULOMB_SMOOTHING", "Candidate", "FeatureLayout", "point_mass_rotational"]

MIN_LINK_MASS = 0.05
"""Links lighter than this [kg] get no link_mass_scale candidate (URDF placeholders)."""

SENSOR_TYPES = tuple(t for t in CATALOGUE if EFFECTS[t].kind == "sensor")
"""Torque-sensor effects: they act on Φ̃ and Γ through the measured τ (module docstring)."""
JOINT_FEATURE_TYPES = tuple(t for t in CATALOGUE if EFFECTS[t].joint_feature_count)
"""Effect types that add per-joint joint-torque columns of their own (EffectType.joint_features)."""
UNMODELLED_TYPE = "unmodelled_joint_torque"
"""The out-of-catalogue probe: a free position-dependent joint torque f_j(q_j) (generic_joint_basis)."""
UNMODELLED_SENSOR_TYPE = "unmodelled_sensor_torque"
"""The probe at sensor level: a position-dependent torque *reading* error f_j(q_j), in Φ̃ and Γ."""
GENERIC_NAMES = ("1", "z", "z2", "z3")
"""Columns of generic_joint_basis: a cubic in z = (q_j − q̄_j)/s_j."""
N_GENERIC = len(GENERIC_NAMES)
ACTUATION_NAMES = ("lag", "gain", "offset") + tuple(f"generic_{g}" for g in GENERIC_NAMES)
"""Actuation features per joint: −τ̇, τ, 1 and the sensor probe's basis (actuation_features)."""
N_ACT = len(ACTUATION_NAMES)


@dataclass(frozen=True)
class LinkInertia:
    """A URDF link's inertia as dynamic parameters in its parent joint's frame (Pinocchio order:
    m, m·c (3), I about the joint origin (Ixx, Ixy, Iyy, Ixz, Iyz, Izz))."""

    name: str
    joint: int  # Pinocchio joint index (1 = root)
    params: np.ndarray

    @property
    def mass(self) -> float:
        return float(self.params[0])


def link_inertias(robot: RobotDescription, min_mass: float = MIN_LINK_MASS) -> list[LinkInertia]:
    """Inertias of the URDF links with mass ≥ MIN_LINK_MASS, expressed in their parent joints
    (RobotDescription.link_inertias: the link-level inertia, needed to scale one link)."""
    return [LinkInertia(name, joint, np.asarray(inertia.toDynamicParameters(), float))
            for name, (joint, inertia) in robot.link_inertias.items() if inertia.mass >= min_mass]


@dataclass
class FeatureLayout:
    """Names and kinds of the feature columns, and the catalogue of candidates over them."""

    robot: RobotDescription
    links: list[LinkInertia]
    q_center: np.ndarray | None = None  # per joint q̄_j, s_j of generic_joint_basis (the diagnosis sets
    q_scale: np.ndarray | None = None   # them from its identification data; default 0 and 1 rad)
    names: list[str] = field(default_factory=list)
    n_rbd: int = 0
    joint_feature0: dict[str, int] = field(default_factory=dict)  # first column of a type's joint features
    _blocks: dict = field(default_factory=dict, init=False, repr=False, compare=False)  # block()'s memo

    def __post_init__(self) -> None:
        nj = self.robot.n_joints
        jn = self.robot.joint_names
        self.names = (
            [f"coulomb:{j}" for j in jn]
            + [f"viscous:{j}" for j in jn]
            + [f"encoder:{j}" for j in jn]
            + ["imu:roll", "imu:pitch"]
            + [f"root:{k}" for k in range(10)]
            + [f"link:{link.name}" for link in self.links]
            + [f"joint_torque:{j}" for j in jn]
            + [f"sensor_gain:{j}" for j in jn]
            + [f"generic:{j}:{g}" for j in jn for g in GENERIC_NAMES]
            + ["baseline:qd", "baseline:qdd", "baseline:udot"]
        )
        for t in JOINT_FEATURE_TYPES:  # per joint, joint_feature_count columns (EffectType.joint_features)
            self.joint_feature0[t] = len(self.names)
            self.names += [f"{t}:{j}:{k}" for j in jn for k in range(EFFECTS[t].joint_feature_count)]
        self.q_center = np.zeros(nj) if self.q_center is None else np.asarray(self.q_center, float)
        self.q_scale = np.ones(nj) if self.q_scale is None else np.maximum(np.asarray(self.q_scale, float), 1e-3)
        self.n_rbd = len(self.names)
        for j in jn:
            self.names += [f"{a}:{j}" for a in ACTUATION_NAMES]
        self.coulomb0, self.viscous0, self.encoder0 = 0, nj, 2 * nj
        self.imu0 = 3 * nj
        self.root0 = self.imu0 + 2
        self.link0 = self.root0 + 10
        self.torque0 = self.link0 + len(self.links)
        self.sensor_gain0 = self.torque0 + nj
        self.generic0 = self.sensor_gain0 + nj
        self.baseline0 = self.generic0 + N_GENERIC * nj
        self.act0 = self.n_rbd

    @property
    def n_features(self) -> int:
        return len(self.names)

    def joint_feature_columns(self) -> np.ndarray:
        """The columns of every type's own joint features (joint_feature0)."""
        nj = self.robot.n_joints
        return np.array([c for t, c0 in self.joint_feature0.items()
                         for c in range(c0, c0 + nj * EFFECTS[t].joint_feature_count)], dtype=int)

    def actuation_feature(self, joint: int, what: str) -> int:
        return self.act0 + N_ACT * joint + ACTUATION_NAMES.index(what)

    def actuation_block(self, joint: int) -> np.ndarray:
        """The feature indices of joint `joint`'s Γ (N_ACT consecutive columns)."""
        return self.act0 + N_ACT * joint + np.arange(N_ACT)

    @cached_property
    def baseline(self) -> Candidate:
        """The command-update sampling term (module docstring): part of every model, never an effect."""
        b = self.baseline0
        lo, hi = parameter_bounds(self.robot, BASELINE)
        return Candidate(BASELINE, "rbd", ("qd", "qdd", "udot"), lo, hi, (b, b + 1, b + 2),
                         joints=tuple(self.robot.joint_names))

    @cached_property
    def candidates(self) -> list[Candidate]:
        """Every registered type's candidates (ordered by their keys), then the out-of-catalogue probes."""
        keyed = [kc for t in CATALOGUE for kc in EFFECTS[t].candidates(self)]
        out = [c for _, c in sorted(keyed, key=lambda kc: kc[0])]
        inf = np.inf
        for j, name in enumerate(self.robot.joint_names):
            g0 = self.generic0 + N_GENERIC * j
            out.append(Candidate(UNMODELLED_TYPE, "rbd", GENERIC_NAMES, (-inf,) * N_GENERIC, (inf,) * N_GENERIC,
                                 tuple(range(g0, g0 + N_GENERIC)), joint=name, in_catalogue=False))
        for j, name in enumerate(self.robot.joint_names):
            g0 = self.generic0 + N_GENERIC * j
            a0 = self.actuation_feature(j, "generic_1")
            features = tuple(range(g0, g0 + N_GENERIC)) + tuple(range(a0, a0 + N_GENERIC))
            out.append(Candidate(UNMODELLED_SENSOR_TYPE, "sensor", GENERIC_NAMES, (-inf,) * N_GENERIC,
                                 (inf,) * N_GENERIC, features, joint=name, in_catalogue=False))
        return out

    def matrix(self, cand: Candidate, payload_com: np.ndarray | None = None,
               lag_scale: dict[str, float] | None = None, nonlinear: dict[str, float] | None = None) -> np.ndarray:
        """A (n_features × n_params): the candidate's columns as combinations of features.

        A catalogue candidate's A is its effect type's (EffectType.matrix), given the model's
        bilinear parts: the payload's CoM (its point-mass rotational inertia), the all-joint lag's
        1/g_j per joint, a non-linear parameter per candidate label (Stribeck velocity)."""
        A = np.zeros((self.n_features, cand.n_params))
        if cand.in_catalogue and cand.type != BASELINE:
            effect_type(cand.type).matrix(self, cand, A, Refinement(payload_com, lag_scale, nonlinear))
        elif cand.type == UNMODELLED_SENSOR_TYPE:  # the same coefficients on Φ̃ (rbd) and Γ columns
            for k in range(N_GENERIC):
                A[cand.features[k], k] = 1.0
                A[cand.features[N_GENERIC + k], k] = 1.0
        else:  # the baseline and the joint probe: one parameter per feature
            for k, f in enumerate(cand.features):
                A[f, k] = 1.0
        return A

    def block(self, cand: Candidate, payload_com: np.ndarray | None = None,
              lag_scale: dict[str, float] | None = None,
              nonlinear: dict[str, float] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(rows, A[rows]): the features a candidate loads (a few of the ~300) and its matrix there.
        Kept for a candidate whose A does not depend on the model's bilinear parts
        (EffectType.refined_by is None): the selection fits ~10⁴ candidate sets of the same ~150."""
        kept = self._blocks.get(id(cand))  # by identity (hashing a candidate's fields costs more than A)
        if kept is not None and kept[0] is cand:
            return kept[1]
        A = self.matrix(cand, payload_com, lag_scale, nonlinear)
        rows = np.flatnonzero(np.any(A != 0.0, axis=1))
        out = (rows, A[rows])
        kind = EFFECTS.get(cand.type) if cand.in_catalogue else None
        if kind is None or kind.refined_by is None:
            out[1].flags.writeable = False
            self._blocks[id(cand)] = (cand, out)  # the candidate kept alive with it: its id stays its own
        return out


def coulomb_regressor(v_joints: np.ndarray, segment: np.ndarray | None, fs: "float | np.ndarray" = 250.0,
                      smoothing: float = COULOMB_SMOOTHING) -> np.ndarray:
    """LP(tanh(q̇/v_s)) per joint: the Coulomb friction torque per unit f_c as it appears after
    the same 10 Hz low-pass as the log (the friction torque switches at velocity reversals;
    the log's torques and accelerations are low-passed, so the regressor is too)."""
    return _lowpass(np.tanh(np.asarray(v_joints, float) / smoothing), segment, fs)


def effect_joint_regressors(v_joints: np.ndarray, segment: np.ndarray | None,
                            fs: "float | np.ndarray" = 250.0) -> dict[str, np.ndarray]:
    """Per type of JOINT_FEATURE_TYPES, its joint_features (N × n_j × k) after the log's low-pass
    (like the Coulomb regressor: the friction switches at velocity reversals)."""
    out = {}
    for t in JOINT_FEATURE_TYPES:
        x = EFFECTS[t].joint_features(v_joints)
        out[t] = _lowpass(x.reshape(len(x), -1), segment, fs).reshape(x.shape)
    return out


def _lowpass(x: np.ndarray, segment: np.ndarray | None, fs: "float | np.ndarray") -> np.ndarray:
    """The log's low-pass of the columns of x (N × m), segment by segment."""
    if segment is None:
        segment = np.zeros(len(x), dtype=int)
    out = np.empty_like(x)
    for seg in np.unique(segment):
        idx = np.flatnonzero(segment == seg)
        out[idx], _ = filter_offline(x[idx], lowpass_taps(_segment_rate(fs, seg)))
    return out


def _segment_rate(fs: "float | np.ndarray", seg: int) -> float:
    """The rate [Hz] of a segment: fs, or fs[seg] for logs of different rates (FilteredLog.segment_rate_hz)."""
    rates = np.asarray(fs, float)
    return float(rates[seg]) if rates.ndim else float(rates)


def generic_joint_basis(q_joints: np.ndarray, layout: "FeatureLayout", segment: np.ndarray | None,
                        fs: "float | np.ndarray" = 250.0) -> np.ndarray:
    """(N × n_j × N_GENERIC) the out-of-catalogue probe's basis of a joint torque f_j(q_j): 1, z, z², z³
    with z = (q_j − q̄_j)/s_j — a spring, a cable, any torque set by where the joint is. No
    velocity terms on purpose: the catalogue's Coulomb and viscous friction cover those, and a
    free function of q̇ would outbid them (it also fits the stick–slip transitions plain Coulomb
    friction leaves, shrink.py). z², z³ pass through the log's low-pass like the Coulomb regressor;
    1 and z are linear in the filtered log."""
    q = np.asarray(q_joints, float)
    z = (q - layout.q_center) / layout.q_scale
    powers = _lowpass(np.stack([z ** 2, z ** 3], axis=-1).reshape(len(q), -1), segment, fs)
    return np.concatenate([np.ones_like(z)[..., None], z[..., None], powers.reshape(z.shape + (2,))], axis=-1)


class RegressorEvaluator:
    """Per-sample rigid-body regressors (Pinocchio, compiled batches: core.batch_dynamics) for a chunk
    of samples."""

    def __init__(self, robot: RobotDescription, layout: FeatureLayout) -> None:
        self.robot = robot
        self.layout = layout
        self.link_cols = [(10 * (link.joint - 1), link.params) for link in layout.links]

    def chunk(self, q: np.ndarray, v: np.ndarray, a: np.ndarray, contacts: np.ndarray, residual: np.ndarray,
              coulomb: np.ndarray, u_dot: np.ndarray | None = None,
              generic: np.ndarray | None = None, tau: np.ndarray | None = None,
              joint_extra: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Generalized-force features E (n × nv × n_rbd) and foot Jacobians (n × n_feet × 3 × nv).

        residual: measured r = Sᵀτ − M q̈ − h (for the contact-force estimate of the encoder term);
        u_dot: derivative of the commanded torque (for the command-update sampling term);
        generic: generic_joint_basis of these samples (the out-of-catalogue probe; None: zeros);
        tau: the measured joint torques (the torque-sensor gain's Φ̃ part; None: zeros);
        joint_extra: effect_joint_regressors of these samples (None: zeros).
        """
        r, lay = self.robot, self.layout
        n, nv, nj = len(q), r.nv, r.n_joints
        E = np.zeros((n, nv, lay.n_rbd))
        jidx = np.arange(nj)
        E[:, 6 + jidx, lay.coulomb0 + jidx] = coulomb
        E[:, 6 + jidx, lay.viscous0 + jidx] = v[:, 6:]
        E[:, 6 + jidx, lay.torque0 + jidx] = 1.0
        E[:, 6:, lay.baseline0] = v[:, 6:]
        E[:, 6:, lay.baseline0 + 1] = a[:, 6:]
        if u_dot is not None:
            E[:, 6:, lay.baseline0 + 2] = u_dot
        if tau is not None:
            E[:, 6 + jidx, lay.sensor_gain0 + jidx] = tau
        if generic is not None:
            for j in range(nj):
                E[:, 6 + j, lay.generic0 + N_GENERIC * j:lay.generic0 + N_GENERIC * (j + 1)] = generic[:, j]
        for t, x in (joint_extra or {}).items():
            k, c0 = x.shape[2], lay.joint_feature0[t]
            for j in range(nj):
                E[:, 6 + j, c0 + k * j:c0 + k * (j + 1)] = x[:, j]
        jac, Y, D = r.batch.regressors(q, v, a)  # the per-sample Pinocchio calls; the rest is batched below
        E[:, :, lay.root0:lay.root0 + 10] = Y[:, :, :10]
        for c, (col, params) in enumerate(self.link_cols):
            E[:, :, lay.link0 + c] = Y[:, :, col:col + 10] @ params
        E[:, :, lay.encoder0:lay.encoder0 + nj] = -D[:, :, 6:]
        E[:, :, lay.imu0:lay.imu0 + 2] = -D[:, :, 3:5]
        # encoder term: the stance feet's contact forces λ (least squares on r = −J_cᵀλ, per contact
        # pattern) through ∂J_c/∂q_j of each stance leg joint j
        patterns, which = np.unique(np.asarray(contacts, bool), axis=0, return_inverse=True)
        items: list[tuple[np.ndarray, int, int, np.ndarray]] = []  # (samples, foot, joint, λ of each sample)
        for p_i, pattern in enumerate(patterns):
            stance = np.flatnonzero(pattern)
            if not len(stance):
                continue
            rows = np.flatnonzero(which.ravel() == p_i)
            JcT = jac[rows][:, stance].reshape(len(rows), -1, nv).transpose(0, 2, 1)  # m × nv × 3s
            lam = -(np.linalg.pinv(JcT) @ residual[rows][:, :, None])[:, :, 0].reshape(len(rows), -1, 3)
            for s_i, foot in enumerate(stance):
                for j in r.leg_joints[foot]:
                    items.append((rows, int(foot), j, lam[:, s_i]))
        if items:
            k = np.concatenate([x[0] for x in items])
            joint = np.concatenate([np.full(len(x[0]), x[2]) for x in items])
            prod = r.batch.jacobian_variation_products(
                q, k, np.concatenate([np.full(len(x[0]), x[1]) for x in items]), 6 + joint,
                np.concatenate([x[3] for x in items]))
            E[k, :, lay.encoder0 + joint] += prod  # (sample, joint) pairs are distinct: a joint has one foot
        return E, jac


def actuation_features(tau: np.ndarray, tau_dot: np.ndarray, generic: np.ndarray | None = None) -> np.ndarray:
    """Features of Γ_j per joint: (n × n_joints × N_ACT) = [−τ̇_j, τ_j, 1, f(q_j) basis] (lag, gain,
    offset, the sensor probe's generic_joint_basis; zeros without `generic`)."""
    base = np.stack([-tau_dot, tau, np.ones_like(tau)], axis=-1)
    if generic is None:
        generic = np.zeros(tau.shape + (N_GENERIC,))
    return np.concatenate([base, generic], axis=-1)
