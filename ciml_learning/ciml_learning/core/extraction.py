"""Contact-invariant model-error extraction (paper §II–III), from Pinocchio dynamics.

Per sample, with r = Sᵀτ − M q̈ − h (all nominal model):

    Φ̃_u = (P_c J_uᵀ)⁺ P_c r                                            (11)
    Γ   = τ − u                                                          (14)
    Φ̃   = J'ᵀ Φ̃'  of the observed entries (8): what the model set learns
    ε   = J'ᵀ Φ̃' − Sᵀ Γ                                                 (17)
    x   = [roll, pitch, q_j, q̇, q̈]  (q without base position and yaw)  (12)

Implementation of (11): with the QR decomposition J_cᵀ = [Q_c Q_u][R; 0], P_c = Q_u Q_uᵀ
and, because J'ᵀ = [J_uᵀ J_cᵀ] is invertible, Q_uᵀ J_uᵀ is square and invertible, so
(P_c J_uᵀ)⁺ P_c r = (Q_uᵀ J_uᵀ)⁻¹ Q_uᵀ r — the same number, one small solve per sample, in
the compiled core (core.batch_dynamics's library: ciml_observe).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ciml_learning.core.batch_dynamics import BatchCoreError, address, check, library
from ciml_learning.core.dynamics import selection_matrix
from ciml_learning.core.projection import (
    DEFAULT_GAMMA,
    contact_invariant_bases,
    generalized_rbd_error,
    leg_coupling,
    require_square_basis,
)
from ciml_learning.core.robot import RobotDescription
from ciml_learning.core.threads import in_order

N_LEARNING_INPUTS_BASE = 2  # roll, pitch


def learning_input_names(robot: RobotDescription) -> tuple[str, ...]:
    """Names of the learning inputs (74 for HyQ): the 50 of eq. (12) (roll, pitch, joints, q̇,
    q̈), then the measured joint torques τ and their rates τ̇ (inputs of the actuation models:
    an actuator's lag and gain are functions of the torque it delivers, Γ ≈ −T τ̇ + (g − 1) τ)."""
    return (
        ("base_roll", "base_pitch")
        + tuple(f"q_{j}" for j in robot.joint_names)
        + tuple(f"qd_{d}" for d in robot.dof_names)
        + tuple(f"qdd_{d}" for d in robot.dof_names)
        + tuple(f"tau_{j}" for j in robot.joint_names)
        + tuple(f"taud_{j}" for j in robot.joint_names)
    )


def roll_pitch(quat_xyzw: np.ndarray) -> np.ndarray:
    """(N × 2) roll and pitch [rad] of base quaternions (ZYX Euler convention)."""
    x, y, z, w = np.moveaxis(np.atleast_2d(quat_xyzw), -1, 0)
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    return np.stack([roll, pitch], axis=-1)


def learning_inputs(q: np.ndarray, v: np.ndarray, a: np.ndarray, tau: np.ndarray, tau_dot: np.ndarray) -> np.ndarray:
    """Learning inputs (N × 74, learning_input_names): eq. (12) without base position and yaw,
    then τ and τ̇ [Nm, Nm/s]."""
    q, v, a, tau, tau_dot = (np.atleast_2d(z) for z in (q, v, a, tau, tau_dot))
    return np.hstack([roll_pitch(q[:, 3:7]), q[:, 7:], v, a, tau, tau_dot])


def actuation_error(tau_measured: np.ndarray, u_commanded: np.ndarray) -> np.ndarray:
    """Γ = τ − u, eq. (14) [Nm]."""
    return np.asarray(tau_measured, dtype=float) - np.asarray(u_commanded, dtype=float)


def combined_error(basis: np.ndarray | None, rbd: np.ndarray, gamma: np.ndarray, S: np.ndarray) -> np.ndarray:
    """ε = J'ᵀ Φ̃' − Sᵀ Γ, eq. (17): the generalized-force error the controller adds, so that
    M q̈ + h + ε = Sᵀu + J_cᵀλ.

    The one home of eq. (17): the controller's trust law, the model set's ε, the identified
    effects' ε and the benchmarks call it. basis: J' (nv × nv, projection.contact_invariant_basis)
    with rbd = Φ̃' (nv); or None with rbd = Φ̃ = J'ᵀΦ̃' already generalized (what a model set
    learns and an identified effect gives). gamma: Γ (n_j); S: dynamics.selection_matrix.
    """
    return (rbd if basis is None else basis.T @ rbd) - S.T @ gamma


def _eq11(foot_jacobians: np.ndarray, basis: np.ndarray, contacts: np.ndarray,
          generalized_force: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (11) per sample in the core: Φ̃' (N × nv) of the forces, or with None the operators
    (N × nv × nv); and the observed mask (N × nv)."""
    jac = np.ascontiguousarray(foot_jacobians, dtype=float)
    n, n_feet, _, nv = jac.shape
    basis = np.ascontiguousarray(basis, dtype=float)
    on = np.ascontiguousarray(contacts, dtype=np.uint8)
    require_square_basis(n_feet, nv)
    if basis.shape != (n, nv, nv) or on.shape != (n, n_feet):
        raise BatchCoreError(f"eq. (11) got J {jac.shape}, J' {basis.shape}, contacts {on.shape}")
    out = np.empty((n, nv) if generalized_force is not None else (n, nv, nv))
    mask = np.empty((n, nv), dtype=np.uint8)
    if generalized_force is None:
        r_address = None
    else:
        r = np.ascontiguousarray(generalized_force, dtype=float)
        if r.shape != (n, nv):
            raise BatchCoreError(f"eq. (11) got forces {r.shape}, expected {(n, nv)}")
        r_address = address(r)
    check(library().ciml_observe(n, n_feet, nv, address(jac), address(basis), address(on), r_address,
                                 address(out), address(mask)), "observe")
    return out, mask.view(bool)


def observation_operators(
    foot_jacobians: np.ndarray, basis: np.ndarray, contacts: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-sample linear maps O_k (N × 18 × nv) with Φ̃'_k = O_k r_k, eq. (11), and the
    observed mask (N × 18). Rows of constrained entries are zero.

    O_k is linear in r, so the diagnosis passes candidate generalized forces through
    the very same operator as the measured error.
    """
    return _eq11(foot_jacobians, basis, contacts, None)


def observe(foot_jacobians: np.ndarray, basis: np.ndarray, contacts: np.ndarray,
            generalized_force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. (11) applied to a batch of generalized forces (N × nv): (Φ̃' (N × 18), mask)."""
    return _eq11(foot_jacobians, basis, contacts, generalized_force)


@dataclass
class ExtractionResult:
    """Training targets of a log (paper §III), one row per sample."""

    t: np.ndarray
    inputs: np.ndarray            # N × 74, learning_inputs (eq. 12, τ, τ̇)
    rbd_error: np.ndarray         # N × 18, Φ̃' (0 where unobserved)
    rbd_observed: np.ndarray      # N × 18
    actuation_error: np.ndarray   # N × 12, Γ
    contacts: np.ndarray          # N × n_feet
    valid: np.ndarray             # N, usable for training
    residual: np.ndarray          # N × nv, r = Sᵀτ − M q̈ − h (nominal model)
    generalized_error: np.ndarray     # N × nv, Φ̃ = J'ᵀΦ̃' of the observed entries (the models' targets)
    generalized_observed: np.ndarray  # N × nv
    leg_coupling: np.ndarray          # N × 6 × n_j, C of projection.leg_coupling
    effort_valid: np.ndarray          # N, rows whose Γ is usable: valid but near contact changes too
                                      # (filters.contact_change_mask)

    def save(self, path: str, robot: RobotDescription, extra: dict | None = None) -> None:
        """Write an .npz (arrays only, loadable with allow_pickle=False), atomically, straight to
        the file (no copy of the arrays in memory)."""
        import json

        from ciml_learning.core.fileio import atomic_write_stream

        meta = {"format_version": 1, "input_names": list(learning_input_names(robot)),
                "rbd_names": list(robot.rbd_error_names), "actuation_names": list(robot.joint_names),
                "foot_names": list(robot.foot_frames), **(extra or {})}
        atomic_write_stream(path, lambda f: np.savez(
            f, t=self.t, inputs=self.inputs, rbd_error=self.rbd_error, rbd_observed=self.rbd_observed,
            actuation_error=self.actuation_error, contacts=self.contacts, valid=self.valid,
            effort_valid=self.effort_valid,
            metadata=np.array(json.dumps(meta))))


def dynamics_batch(robot: RobotDescription, q: np.ndarray, v: np.ndarray,
                   a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nominal M q̈ + h (N × nv, RNEA) and foot Jacobians (N × n_feet × 3 × nv), one compiled
    Pinocchio batch (core.batch_dynamics)."""
    return robot.batch.inverse_dynamics(q, v, a)


EXTRACTION_CHUNK = 4096
"""Samples extract() solves at once. Its intermediates are per sample and large (foot Jacobians,
J' and the result's own rows: some 6 KB a sample, three times the result), so chunks bound them
to about 30 MB whatever the log's length; the numbers do not depend on the chunk (every sample is
solved on its own)."""


def extract(
    robot: RobotDescription,
    q: np.ndarray,
    v: np.ndarray,
    a: np.ndarray,
    tau: np.ndarray,
    u: np.ndarray,
    contacts: np.ndarray,
    t: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    gamma: float = DEFAULT_GAMMA,
    tau_dot: np.ndarray | None = None,
    chunk: int = EXTRACTION_CHUNK,
    effort_valid: np.ndarray | None = None,
) -> ExtractionResult:
    """Batch extraction of Φ̃' (eq. 11), Γ (eq. 14) and the learning inputs from a filtered log
    (τ̇: the filtered torque rate; None leaves its inputs NaN, unusable for learning), `chunk`
    samples at a time into the result's rows (EXTRACTION_CHUNK). effort_valid: the rows whose Γ
    is usable (FilteredLog.effort_valid; None: `valid`)."""
    q, v, a, tau, u = (np.asarray(x, float) for x in (q, v, a, tau, u))
    n = len(q)
    rows = {
        "q": q, "v": v, "a": a, "tau": tau, "u": u, "contacts": np.asarray(contacts, dtype=bool),
        "t": np.arange(n, dtype=float) if t is None else np.asarray(t, float),
        "valid": np.ones(n, dtype=bool) if valid is None else np.asarray(valid, dtype=bool),
        "tau_dot": np.full(np.shape(tau), np.nan) if tau_dot is None else np.asarray(tau_dot, float),
    }
    rows["effort_valid"] = rows["valid"] if effort_valid is None else np.asarray(effort_valid, dtype=bool)
    if n <= chunk:
        return _extract_chunk(robot, gamma, **rows)
    out = {"t": rows["t"], "contacts": rows["contacts"]}  # passed through, as in one chunk

    def part(start: int) -> ExtractionResult:
        return _extract_chunk(robot, gamma, **{k: x[start:start + chunk] for k, x in rows.items()})

    starts = range(0, n, chunk)
    for start, result in zip(starts, in_order(part, starts)):  # the chunks on the process's cores (core.threads)
        for name, x in vars(result).items():
            if name in ("t", "contacts"):
                continue
            if name not in out:
                out[name] = np.empty((n,) + x.shape[1:], x.dtype)
            out[name][start:start + len(x)] = x
    return ExtractionResult(**out)


def _extract_chunk(robot: RobotDescription, gamma: float, q: np.ndarray, v: np.ndarray, a: np.ndarray,
                   tau: np.ndarray, u: np.ndarray, contacts: np.ndarray, t: np.ndarray, valid: np.ndarray,
                   tau_dot: np.ndarray, effort_valid: np.ndarray) -> ExtractionResult:
    """extract() of one chunk (its arguments as arrays of one length)."""
    S = selection_matrix(robot)
    id_terms, jac = dynamics_batch(robot, q, v, a)
    residual = tau @ S - id_terms
    basis = contact_invariant_bases(jac, robot.leg_joints, gamma)
    phi, mask = observe(jac, basis, contacts, residual)
    ok = np.all(np.isfinite(phi), axis=1)
    phi[~ok] = 0.0
    mask[~ok] = False
    generalized, generalized_mask = generalized_rbd_error(basis, phi, mask, robot.leg_joints)
    return ExtractionResult(
        t=t,
        inputs=learning_inputs(q, v, a, tau, tau_dot),
        rbd_error=phi,
        rbd_observed=mask,
        actuation_error=actuation_error(tau, u),
        contacts=contacts,
        valid=valid & ok,
        residual=residual,
        generalized_error=generalized,
        generalized_observed=generalized_mask,
        leg_coupling=leg_coupling(basis, robot.leg_joints),
        effort_valid=effort_valid.copy(),
    )
