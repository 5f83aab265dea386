"""The gait references' leg inverse kinematics, compiled (numba): damped Newton per leg on the
foot positions with the C++ core's kinematics at each iterate, and the joint rates that carry
the feet along (ciml_control.references.LegIK is the interface).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..native import FOOT_ACCELERATION, FOOT_KINEMATICS, ccall
from .linalg import solve_small


@njit(cache=True)
def leg_newton_step(J: np.ndarray, feet: np.ndarray, targets: np.ndarray, q: np.ndarray, qidx: np.ndarray,
                    cols: np.ndarray, tol: float, damping: float, max_step: float):
    """One damped-Newton step of every leg on the foot positions, q updated in place.

    J (n_feet × 3 × nv) world-aligned foot Jacobians and `feet` (n_feet × 3) the foot
    positions at q; the step of leg i solves (BᵢᵀBᵢ + damping I) s = Bᵢᵀ eᵢ (Bᵢ: the leg's
    3 × n_leg block, eᵢ the foot error) and is shortened to at most `max_step` [rad].
    Returns (converged, largest |error|): converged (no step taken) when every error
    component is below tol; NaN errors never converge."""
    nf = J.shape[0]
    nl = cols.shape[1]
    converged = True
    worst = 0.0
    for i in range(nf):
        for a in range(3):
            e = abs(targets[i, a] - feet[i, a])
            if not e < tol:
                converged = False
            if e > worst or e != e:
                worst = e
    if converged:
        return True, worst
    for i in range(nf):
        N = np.empty((nl, nl))
        r = np.empty(nl)
        for b in range(nl):
            s = 0.0
            for a in range(3):
                s += J[i, a, cols[i, b]] * (targets[i, a] - feet[i, a])
            r[b] = s
            for c in range(nl):
                t = 0.0
                for a in range(3):
                    t += J[i, a, cols[i, b]] * J[i, a, cols[i, c]]
                N[b, c] = t + (damping if b == c else 0.0)
        step = solve_small(N, r)
        norm = 0.0
        for b in range(nl):
            norm += step[b] * step[b]
        scale = min(1.0, max_step / max(math.sqrt(norm), 1e-300))
        for b in range(nl):
            q[qidx[i, b]] += step[b] * scale
    return False, worst


@njit(cache=True)
def leg_solve(J: np.ndarray, targets: np.ndarray, base: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Joint rates of every leg (n_feet × n_leg): Bᵢ xᵢ = targetᵢ − J_base,ᵢ base."""
    nf = J.shape[0]
    nl = cols.shape[1]
    out = np.empty((nf, nl))
    for i in range(nf):
        B = np.empty((3, nl))
        r = np.empty(3)
        for a in range(3):
            s = targets[i, a]
            for k in range(6):
                s -= J[i, a, k] * base[k]
            r[a] = s
            for b in range(nl):
                B[a, b] = J[i, a, cols[i, b]]
        out[i] = solve_small(B, r)
    return out


@njit(cache=True)
def leg_ik(fns, dyn, q: np.ndarray, targets: np.ndarray, qidx: np.ndarray, cols: np.ndarray, tol: float,
           max_iter: int, J: np.ndarray, feet: np.ndarray):
    """Leg inverse kinematics: damped Newton per leg on the foot positions (leg_newton_step)
    with the core's kinematics at each iterate (ciml_foot_kinematics, fns and dyn as in
    control_step); q updated in place, J and feet left at the final q. Returns
    (converged, largest |error|)."""
    worst = np.inf
    for _ in range(max_iter):
        ccall(fns[FOOT_KINEMATICS], (dyn, q.ctypes.data, J.ctypes.data, feet.ctypes.data))
        done, worst = leg_newton_step(J, feet, targets, q, qidx, cols, tol, 1e-12, 0.5)
        if done:
            return True, worst
    return False, worst


@njit(cache=True)
def leg_rates(fns, dyn, q: np.ndarray, J: np.ndarray, R: np.ndarray, E: np.ndarray, E_dot: np.ndarray,
              dp: np.ndarray, ddp: np.ndarray, drpy: np.ndarray, ddrpy: np.ndarray, feet_v: np.ndarray,
              feet_a: np.ndarray, cols: np.ndarray):
    """(v, a) of the reference at its IK solution q (J: the foot Jacobians at q) for the
    base's world velocity dp, acceleration ddp and roll-pitch-yaw rates drpy, ddrpy (R its
    rotation, E and E_dot Pinocchio's local rpy Jacobian and its time derivative) and the
    feet's velocities and accelerations:
        ω = E ṙ,  v_lin = Rᵀ ṗ,  ω̇ = E r̈ + Ė ṙ,  a_lin = Rᵀ p̈ − ω × v_lin,
        J_leg q̇_leg = ṗ_foot − J_base v_base,
        J_leg q̈_leg = p̈_foot − (classical foot acceleration at zero joint acceleration)."""
    nv = J.shape[2]
    v = np.zeros(nv)
    a = np.zeros(nv)
    for i in range(3):
        s_w = 0.0
        s_dw = 0.0
        s_v = 0.0
        s_a = 0.0
        for k in range(3):
            s_w += E[i, k] * drpy[k]
            s_dw += E[i, k] * ddrpy[k] + E_dot[i, k] * drpy[k]
            s_v += R[k, i] * dp[k]
            s_a += R[k, i] * ddp[k]
        v[3 + i] = s_w
        a[3 + i] = s_dw
        v[i] = s_v
        a[i] = s_a
    w0, w1, w2 = v[3], v[4], v[5]
    a[0] -= w1 * v[2] - w2 * v[1]
    a[1] -= w2 * v[0] - w0 * v[2]
    a[2] -= w0 * v[1] - w1 * v[0]
    rates = leg_solve(J, feet_v, v[:6].copy(), cols)
    for i in range(cols.shape[0]):
        for b in range(cols.shape[1]):
            v[cols[i, b]] = rates[i, b]
    drift = np.empty((J.shape[0], 3))
    ccall(fns[FOOT_ACCELERATION], (dyn, q.ctypes.data, v.ctypes.data, a.ctypes.data, drift.ctypes.data))
    acc = leg_solve(J, feet_a - drift, np.zeros(6), cols)
    for i in range(cols.shape[0]):
        for b in range(cols.shape[1]):
            a[cols[i, b]] = acc[i, b]
    return v, a
