"""Compiled (numba) small dense linear algebra of the 250 Hz control step.

The controller's matrices are tiny (18 × 18 at most); numpy spends far more time in
its Python wrappers than in arithmetic on them (an `np.linalg.qr(..., "complete")`
takes ~20 µs for 18 × 12). These kernels do the same algebra in one compiled call
each, with explicit loops (no BLAS threads involved):

- `qr_complete`: Householder QR with LAPACK's conventions (dgeqr2/dorg2r: β = −sign(α)‖x‖,
  Q = H₁⋯H_n), so Q and R equal numpy's `np.linalg.qr(A, "complete")` to rounding;
- `contact_decomposition`: QR of J_cᵀ and the row space of Q_uᵀSᵀ (see ciml_control.qp);
- `feedforward_matrices`: the QP matrices of eq. (18–21);
- `projected_pinv_apply`: (Q_uᵀSᵀ)⁺ Q_uᵀ x of the feedback linearisation, eq. (24);
- `min_norm_correction`, `max_violation`: the QP answer's equality polish and check.

Compiled on first use and cached on disk (numba `cache=True`).
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from .native import DIFFERENCE, FOOT_ACCELERATION, FOOT_KINEMATICS, QP_DROP, QP_SOLVE, TERMS, ccall


def arg(x, dtype=np.float64) -> np.ndarray:
    """x as a C-contiguous array of dtype (no copy if it is one already). numba compiles
    one specialisation per argument layout (and per read-only flag): the control path
    passes writable C arrays."""
    return np.ascontiguousarray(x, dtype=dtype)


@njit(cache=True)
def qr_complete(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A (m × n, m ≥ n) = Q [R; 0]: Q (m × m) orthogonal, R (n × n) upper triangular."""
    m, n = A.shape
    W = A.copy()
    tau = np.zeros(n)
    for j in range(n):
        alpha = W[j, j]
        xn2 = 0.0
        for i in range(j + 1, m):
            xn2 += W[i, j] * W[i, j]
        if xn2 == 0.0:
            continue  # H_j = I (LAPACK dlarfg with a zero tail)
        beta = -math.copysign(math.sqrt(alpha * alpha + xn2), alpha)
        tau[j] = (beta - alpha) / beta
        scale = 1.0 / (alpha - beta)
        for i in range(j + 1, m):
            W[i, j] *= scale
        W[j, j] = beta
        for k in range(j + 1, n):  # H_j applied to the trailing columns
            s = W[j, k]
            for i in range(j + 1, m):
                s += W[i, j] * W[i, k]
            s *= tau[j]
            W[j, k] -= s
            for i in range(j + 1, m):
                W[i, k] -= s * W[i, j]
    Q = np.eye(m)
    for j in range(n - 1, -1, -1):  # Q = H_0 (H_1 (⋯ H_{n−1} I)), rows/columns ≥ j only
        t = tau[j]
        if t == 0.0:
            continue
        for k in range(j, m):
            s = Q[j, k]
            for i in range(j + 1, m):
                s += W[i, j] * Q[i, k]
            s *= t
            Q[j, k] -= s
            for i in range(j + 1, m):
                Q[i, k] -= s * W[i, j]
    R = np.zeros((n, n))
    for i in range(n):
        for k in range(i, n):
            R[i, k] = W[i, k]
    return Q, R


@njit(cache=True)
def contact_jacobian(foot_jacobians: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """Stacked linear Jacobians (3 n_c × nv) of the feet in contact."""
    nf, _, nv = foot_jacobians.shape
    nc = 0
    for i in range(nf):
        if contacts[i]:
            nc += 1
    Jc = np.empty((3 * nc, nv))
    r = 0
    for i in range(nf):
        if contacts[i]:
            for a in range(3):
                for k in range(nv):
                    Jc[r, k] = foot_jacobians[i, a, k]
                r += 1
    return Jc


@njit(cache=True)
def contact_decomposition(foot_jacobians: np.ndarray, contacts: np.ndarray, tol: float):
    """(Q_c, Q_u, R, U_r, has_U_r): J_cᵀ = [Q_c Q_u][R; 0]; U_r an orthonormal basis of the
    row space of Q_uᵀSᵀ when it is rank deficient (has_U_r), see ciml_control.qp."""
    nv = foot_jacobians.shape[2]
    Jc = contact_jacobian(foot_jacobians, contacts)
    nc3 = Jc.shape[0]
    if nc3 > 0:
        Q, R = qr_complete(np.ascontiguousarray(Jc.T))
        Q_c = np.ascontiguousarray(Q[:, :nc3])
        Q_u = np.ascontiguousarray(Q[:, nc3:])
        B = np.zeros((6, 6))  # J_c,baseᵀ J_c,base
        for i in range(6):
            for j in range(6):
                s = 0.0
                for r in range(nc3):
                    s += Jc[r, i] * Jc[r, j]
                B[i, j] = s
        w, V = np.linalg.eigh(B)
        thr = tol * max(w[5], 1.0)
        nb = 0
        for i in range(6):
            if w[i] < thr:
                nb += 1
        Nb = np.empty((6, nb))
        c = 0
        for i in range(6):
            if w[i] < thr:
                Nb[:, c] = V[:, i]
                c += 1
    else:
        Q_c = np.zeros((nv, 0))
        Q_u = np.eye(nv)
        R = np.zeros((0, 0))
        nb = 6
        Nb = np.eye(6)
    nu = Q_u.shape[1]
    if nb == 0:
        return Q_c, Q_u, R, np.zeros((nu, 0)), False
    W = np.zeros((nu, nb))  # Q_uᵀ [n_b; 0]
    for i in range(nu):
        for c in range(nb):
            s = 0.0
            for k in range(6):
                s += Q_u[k, i] * Nb[k, c]
            W[i, c] = s
    if nb == 1:  # complement of one vector from one Householder reflection
        v = W[:, 0].copy()
        v[0] += 1.0 if W[0, 0] >= 0 else -1.0
        f = 2.0 / np.dot(v, v)
        U = np.empty((nu, nu - 1))
        for i in range(nu):
            for k in range(1, nu):
                U[i, k - 1] = (1.0 if i == k else 0.0) - f * v[i] * v[k]
        return Q_c, Q_u, R, U, True
    Qw, _ = qr_complete(W)
    return Q_c, Q_u, R, np.ascontiguousarray(Qw[:, nb:]), True


@njit(cache=True)
def _row_space(Q_u: np.ndarray, x: np.ndarray, U_r: np.ndarray, has_ur: bool):
    """(A, y): A = Q_uᵀSᵀ (joint rows of Q_u) and y = Q_uᵀ x, both rotated onto the row
    space by U_rᵀ when Q_uᵀSᵀ is rank deficient; also ‖dropped part of y‖."""
    nv, nu = Q_u.shape
    nj = nv - 6
    A = np.empty((nu, nj))
    y = np.empty(nu)
    for i in range(nu):
        s = 0.0
        for k in range(nv):
            s += Q_u[k, i] * x[k]
        y[i] = s
        for j in range(nj):
            A[i, j] = Q_u[6 + j, i]
    if not has_ur:
        return A, y, 0.0
    nr = U_r.shape[1]
    A2 = np.zeros((nr, nj))
    y2 = np.zeros(nr)
    for r in range(nr):
        s = 0.0
        for i in range(nu):
            u = U_r[i, r]
            s += u * y[i]
            for j in range(nj):
                A2[r, j] += u * A[i, j]
        y2[r] = s
    dropped = 0.0
    for i in range(nu):
        s = y[i]
        for r in range(nr):
            s -= U_r[i, r] * y2[r]
        dropped += s * s
    return A2, y2, math.sqrt(dropped)


@njit(cache=True)
def _spd_solve(S: np.ndarray, b: np.ndarray) -> np.ndarray:
    """S x = b for a symmetric positive definite S (Cholesky); NaN if S is not."""
    n = S.shape[0]
    L = np.zeros((n, n))
    for j in range(n):
        d = S[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return np.full(n, np.nan)
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, n):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    z = np.empty(n)
    for i in range(n):
        s = b[i]
        for k in range(i):
            s -= L[i, k] * z[k]
        z[i] = s / L[i, i]
    x = np.empty(n)
    for i in range(n - 1, -1, -1):
        s = z[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return x


@njit(cache=True)
def min_norm_apply(A: np.ndarray, y: np.ndarray) -> np.ndarray:
    """A⁺ y = Aᵀ (A Aᵀ)⁻¹ y for A with full row rank."""
    m, n = A.shape
    S = np.empty((m, m))
    for i in range(m):
        for j in range(i, m):
            s = 0.0
            for k in range(n):
                s += A[i, k] * A[j, k]
            S[i, j] = s
            S[j, i] = s
    z = _spd_solve(S, y)
    out = np.zeros(n)
    for i in range(m):
        for k in range(n):
            out[k] += A[i, k] * z[i]
    return out


@njit(cache=True)
def projected_pinv_apply(M_upper: np.ndarray, foot_jacobians: np.ndarray, contacts: np.ndarray,
                         qdd: np.ndarray, tol: float) -> np.ndarray:
    """(P_c Sᵀ)⁺ P_c M q̈ = (Q_uᵀSᵀ)⁺ Q_uᵀ M q̈, eq. (24), with M given by its upper triangle."""
    nv = qdd.shape[0]
    Mq = np.zeros(nv)
    for i in range(nv):
        s = 0.0
        for k in range(nv):
            s += (M_upper[i, k] if k >= i else M_upper[k, i]) * qdd[k]
        Mq[i] = s
    _, Q_u, _, U_r, has_ur = contact_decomposition(foot_jacobians, contacts, tol)
    A, y, _ = _row_space(Q_u, Mq, U_r, has_ur)
    return min_norm_apply(A, y)


@njit(cache=True)
def feedforward_matrices(M_upper: np.ndarray, h: np.ndarray, foot_jacobians: np.ndarray, contacts: np.ndarray,
                         qdd: np.ndarray, epsilon: np.ndarray, F: np.ndarray, f_min: float, tol: float):
    """The QP of eq. (18–21) (see ciml_control.qp.build_feedforward_qp):
    (A, b, unrealizable, lam0, G, C, c_u, Q_u, rhs) with M given by its upper triangle
    and F the 9 × 3 friction-cone rows of one foot."""
    nv = h.shape[0]
    nj = nv - 6
    rhs = np.empty(nv)
    for i in range(nv):
        s = 0.0
        for k in range(nv):
            s += (M_upper[i, k] if k >= i else M_upper[k, i]) * qdd[k]
        rhs[i] = s + h[i] + epsilon[i]
    Q_c, Q_u, R, U_r, has_ur = contact_decomposition(foot_jacobians, contacts, tol)
    A, b, unrealizable = _row_space(Q_u, rhs, U_r, has_ur)
    nc3 = Q_c.shape[1]
    # λ = R⁻¹ Q_cᵀ (rhs − Sᵀu) = lam0 − G u (back substitution: R is upper triangular)
    X = np.empty((nc3, 1 + nj))
    for i in range(nc3):
        s = 0.0
        for k in range(nv):
            s += Q_c[k, i] * rhs[k]
        X[i, 0] = s
        for j in range(nj):
            X[i, 1 + j] = Q_c[6 + j, i]
    for c in range(1 + nj):
        for i in range(nc3 - 1, -1, -1):
            s = X[i, c]
            for k in range(i + 1, nc3):
                s -= R[i, k] * X[k, c]
            X[i, c] = s / R[i, i]
    lam0 = np.ascontiguousarray(X[:, 0])
    G = np.ascontiguousarray(X[:, 1:])
    n_c = nc3 // 3
    nr = F.shape[0]
    C = np.empty((nr * n_c, nj))
    c_u = np.empty(nr * n_c)
    for f in range(n_c):  # F λ_f ≤ d: C = −F G_f, c_u = d − F lam0_f
        for r in range(nr):
            row = f * nr + r
            s = 0.0
            for a in range(3):
                s += F[r, a] * lam0[3 * f + a]
            c_u[row] = (-f_min if r == nr - 1 else 0.0) - s
            for j in range(nj):
                t = 0.0
                for a in range(3):
                    t += F[r, a] * G[3 * f + a, j]
                C[row, j] = -t
    return A, b, unrealizable, lam0, G, C, c_u, Q_u, rhs


@njit(cache=True)
def min_norm_correction(A: np.ndarray, b: np.ndarray, x: np.ndarray) -> np.ndarray:
    """x − Aᵀ (A Aᵀ)⁻¹ (A x − b): the nearest point to x on A u = b (A full row rank)."""
    m, n = A.shape
    if m == 0:
        return x.copy()
    r = np.empty(m)
    for i in range(m):
        s = -b[i]
        for k in range(n):
            s += A[i, k] * x[k]
        r[i] = s
    return x - min_norm_apply(A, r)


@njit(cache=True)
def max_violation(A, b, C, l, c_u, lb, ub, u) -> float:
    """Largest violation of A u = b, l ≤ C u ≤ c_u, lb ≤ u ≤ ub (0 if feasible; NaN if
    any of them is NaN)."""
    worst = 0.0
    n = u.shape[0]
    for i in range(A.shape[0]):
        s = -b[i]
        for k in range(n):
            s += A[i, k] * u[k]
        worst = max(worst, abs(s))
        if s != s:
            return np.nan
    for i in range(C.shape[0]):
        s = 0.0
        for k in range(n):
            s += C[i, k] * u[k]
        worst = max(worst, l[i] - s, s - c_u[i])
        if s != s:
            return np.nan
    for k in range(n):
        worst = max(worst, lb[k] - u[k], u[k] - ub[k])
        if u[k] != u[k]:
            return np.nan
    return worst


@njit(cache=True)
def all_finite(a: np.ndarray) -> bool:
    for x in a.flat:
        if not np.isfinite(x):
            return False
    return True


# --- leg inverse kinematics (ciml_control.references.LegIK) ---------------------------------


@njit(cache=True)
def _solve_small(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """A x = b by Gaussian elimination with partial pivoting (A small and square)."""
    n = A.shape[0]
    M = A.copy()
    x = b.copy()
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(M[r, c]) > abs(M[p, c]):
                p = r
        if p != c:
            for k in range(n):
                M[c, k], M[p, k] = M[p, k], M[c, k]
            x[c], x[p] = x[p], x[c]
        for r in range(c + 1, n):
            f = M[r, c] / M[c, c]
            for k in range(c, n):
                M[r, k] -= f * M[c, k]
            x[r] -= f * x[c]
    for r in range(n - 1, -1, -1):
        s = x[r]
        for k in range(r + 1, n):
            s -= M[r, k] * x[k]
        x[r] = s / M[r, r]
    return x


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
        step = _solve_small(N, r)
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
        out[i] = _solve_small(B, r)
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


# --- the QP answer (ciml_control.qp.FeedforwardQP.solve) ------------------------------------


@njit(cache=True)
def problem_finite(rhs, C, c_u, A, b) -> bool:
    """All entries of the QP data finite."""
    return all_finite(rhs) and all_finite(C) and all_finite(c_u) and all_finite(A) and all_finite(b)


@njit(cache=True)
def polish_and_check(A, b, C, l, c_u, lb, ub, lam0, G, x):
    """(u, λ, worst violation, scale, u finite) of a solver answer x: u = the min-norm
    correction of x onto A u = b, λ = lam0 − G u (eq. 20), the largest constraint
    violation at u and the scale max(1, ‖b‖∞, ‖c_u‖∞) it is judged against."""
    u = min_norm_correction(A, b, x)
    scale = 1.0
    for i in range(b.shape[0]):
        scale = max(scale, abs(b[i]))
    for i in range(c_u.shape[0]):
        scale = max(scale, abs(c_u[i]))
    worst = max_violation(A, b, C, l, c_u, lb, ub, u)
    lam = np.empty(lam0.shape[0])
    for i in range(lam0.shape[0]):
        s = lam0[i]
        for k in range(u.shape[0]):
            s -= G[i, k] * u[k]
        lam[i] = s
    return u, lam, worst, scale, all_finite(u)


# --- the QP solve and the whole control step (the C++ core by address: ciml_control.native) --

INFINITY = 1e20
"""The QP's bound for 'no bound' (proxsuite takes ±1e20 as infinite)."""
QP_SOLVED = 0
QP_EXCEPTION = -1
QP_NON_FINITE = -2
QP_VIOLATION = -3
"""Status codes of `solve_feedforward` besides proxsuite's QPSolverOutput + 1."""

STATE_NON_FINITE = 1
REFERENCE_NON_FINITE = 2
EPSILON_REJECTED = 4
"""Flags of `control_step`."""


@njit(cache=True)
def eliminate_equality(A, b, H, g, C, l, c_u, lb, ub):
    """The QP min ½uᵀHu + gᵀu, A u = b, l ≤ C u ≤ c_u, lb ≤ u ≤ ub (A: full row rank) in
    the coordinates z of the equality's solutions u = u₀ + N z (QR of Aᵀ = [Q₁ N][R; 0],
    u₀ = Q₁ R⁻ᵀ b its minimum-norm solution, N an orthonormal basis of null(A)):

        min ½zᵀ(NᵀHN)z + (Nᵀ(H u₀ + g))ᵀz   s.t.   l − C u₀ ≤ C N z ≤ c_u − C u₀,
                                                  lb − u₀ ≤ N z ≤ ub − u₀.

    Returns (u₀, N, H_z, g_z, C_z, l_z, c_z). For the feedforward QP (eq. 18–21, W_u = I,
    g = 0) H_z = I and g_z = 0: the torque of least norm, eq. (19) holding exactly."""
    m, n = A.shape
    u0 = np.zeros(n)
    if m > 0:
        Q, R = qr_complete(np.ascontiguousarray(A.T))
        y = np.empty(m)  # Rᵀ y = b
        for i in range(m):
            s = b[i]
            for k in range(i):
                s -= R[k, i] * y[k]
            y[i] = s / R[i, i]
        for i in range(n):
            s = 0.0
            for k in range(m):
                s += Q[i, k] * y[k]
            u0[i] = s
        N = np.ascontiguousarray(Q[:, m:])
    else:
        N = np.eye(n)
    r = n - m
    HN = H @ N
    H_z = np.ascontiguousarray(N.T @ HN)
    g_z = N.T @ (H @ u0 + g)
    nc = C.shape[0]
    C_z = np.empty((nc + n, r))
    l_z = np.empty(nc + n)
    c_z = np.empty(nc + n)
    CN = C @ N
    Cu0 = C @ u0
    for i in range(nc):
        C_z[i] = CN[i]
        l_z[i] = l[i] - Cu0[i]
        c_z[i] = c_u[i] - Cu0[i]
    for i in range(n):
        C_z[nc + i] = N[i]
        l_z[nc + i] = lb[i] - u0[i]
        c_z[nc + i] = ub[i] - u0[i]
    return u0, N, H_z, g_z, C_z, l_z, c_z


@njit(cache=True)
def solve_feedforward(fns, qp, H, g, A, b, C, l, c_u, lb, ub, lam0, G, rhs, tolerance):
    """Solve the QP of eq. (18–21) with the core's proxsuite solver, in the coordinates of
    eliminate_equality (a QP in 12 − rank(A) variables with inequalities only: ~5× faster
    than the same QP over u with eq. 19 as equality rows, same answer to the tolerance),
    then polish and check the answer on the original problem (polish_and_check).
    fns: ciml_control.native.function_table(); qp: a native.QpSolvers handle.
    Returns (status, u, λ, iterations, worst violation): status QP_SOLVED, QP_NON_FINITE
    (data not finite, nothing solved), QP_VIOLATION (the answer violates a constraint by
    more than tolerance · scale; the solver is dropped), QP_EXCEPTION, or proxsuite's
    QPSolverOutput + 1 (not solved; the solver is dropped)."""
    nj = H.shape[0]
    u = np.zeros(nj)
    lam = np.zeros(lam0.shape[0])
    if not (problem_finite(rhs, C, c_u, A, b) and all_finite(H) and all_finite(g)):
        return QP_NON_FINITE, u, lam, 0, 0.0
    u0, N, H_z, g_z, C_z, l_z, c_z = eliminate_equality(A, b, H, g, C, l, c_u, lb, ub)
    r = N.shape[1]
    iterations = 0
    x = u0
    sizes = np.array([r, 0, C_z.shape[0], 0], dtype=np.int64)
    if r > 0:  # else A u = b has one solution
        z = np.zeros(r)
        none = np.zeros(1)  # A_z, b_z (no rows) and the box (none) are not read
        info = np.zeros(2, dtype=np.int64)
        ccall(fns[QP_SOLVE], (qp, sizes.ctypes.data, H_z.ctypes.data, g_z.ctypes.data, none.ctypes.data,
                       none.ctypes.data, C_z.ctypes.data, l_z.ctypes.data, c_z.ctypes.data, none.ctypes.data,
                       none.ctypes.data, z.ctypes.data, info.ctypes.data))
        iterations = info[1]
        if info[0] != QP_SOLVED:
            return info[0], u, lam, iterations, 0.0
        x = u0 + N @ z
    u, lam, worst, scale, finite = polish_and_check(A, b, C, l, c_u, lb, ub, lam0, G, x)
    if not finite or not worst <= tolerance * scale:
        if r > 0:
            ccall(fns[QP_DROP], (qp, sizes.ctypes.data))
        return QP_VIOLATION, u, lam, iterations, worst
    return QP_SOLVED, u, lam, iterations, worst


@njit(cache=True)
def desired_terms(fns, dyn, q, v, key, M, h, J) -> None:
    """M, h, J of the core's model `dyn` at (q, v) into the buffers, skipped when key
    (q, v, valid flag) already holds this very (q, v)."""
    nq = q.shape[0]
    nv = v.shape[0]
    same = key[nq + nv] == 1.0
    if same:
        for i in range(nq):
            if key[i] != q[i]:
                same = False
                break
    if same:
        for i in range(nv):
            if key[nq + i] != v[i]:
                same = False
                break
    if same:
        return
    key[nq + nv] = 0.0
    ccall(fns[TERMS], (dyn, q.ctypes.data, v.ctypes.data, M.ctypes.data, h.ctypes.data, J.ctypes.data))
    key[:nq] = q
    key[nq:nq + nv] = v
    key[nq + nv] = 1.0


@njit(cache=True)
def clip_feedback(u_ff, u_lin, limits) -> None:
    """u_lin ← clip(u_ff + u_lin, ±limits) − u_ff: the total within the torque limits,
    the clipping taken from the linearisation part."""
    for j in range(u_ff.shape[0]):
        t = min(max(u_ff[j] + u_lin[j], -limits[j]), limits[j])
        u_lin[j] = t - u_ff[j]


class ControlWorkspace(NamedTuple):
    """What the compiled control step keeps between steps (IdController builds it once; the
    arrays are updated in place): the C++ core's handles (ciml_control.native) and the
    buffers of the nominal terms at the reference (cached by `key`) and at the measured state."""

    functions: np.ndarray     # addresses of the core's C functions (native.function_table())
    dyn_des: int              # native.Dynamics handle for the terms at the reference (qᵈ, q̇ᵈ)
    dyn_meas: int             # native.Dynamics handle for the terms at the measured (q, v)
    qp: int                   # native.QpSolvers handle (one proxsuite solver per problem size)
    key: np.ndarray           # (qᵈ, q̇ᵈ, valid flag) the *_des buffers hold (desired_terms)
    M_des: np.ndarray         # nv × nv, upper triangle
    h_des: np.ndarray         # nv
    J_des: np.ndarray         # n_feet × 3 × nv
    M_meas: np.ndarray
    h_meas: np.ndarray
    J_meas: np.ndarray


class ControlParameters(NamedTuple):
    """The controller's constant parameters (IdController, fixed at construction)."""

    H: np.ndarray             # W_u of the QP cost ½uᵀW_u u (n_j × n_j; identity)
    g: np.ndarray             # linear cost (n_j; zeros)
    limits: np.ndarray        # torque limits (n_j) [Nm]
    cone: np.ndarray          # friction-cone rows of one foot (9 × 3, qp.friction_cone_matrix)
    f_min: float              # smallest normal force of a stance foot [N]
    rank_tol: float           # rank test of Q_uᵀSᵀ in the QP (qp.RANK_TOL)
    qp_tolerance: float       # largest accepted constraint violation, relative (FeedforwardQP.tolerance)
    kp_lin: np.ndarray        # feedback-linearisation gains (nv) [1/s²]
    kd_lin: np.ndarray        # (nv) [1/s]
    feedback_rank_tol: float  # rank test in eq. (24) (feedback.CONTACT_RANK_TOL)
    feedback_measured: bool   # P_c of eq. (24) from the measured contacts (else the reference's)


class ControlInput(NamedTuple):
    """One step's inputs: the measured state and contacts, the reference point, ε (eq. 17)."""

    q: np.ndarray             # measured configuration (Pinocchio, nq)
    v: np.ndarray             # measured velocity (nv)
    contacts: np.ndarray      # measured contacts (n_feet, bool)
    ref_q: np.ndarray         # qᵈ (nq)
    ref_v: np.ndarray         # q̇ᵈ (nv)
    ref_a: np.ndarray         # q̈ᵈ (nv)
    ref_contacts: np.ndarray  # the reference contact schedule (n_feet, bool)
    epsilon: np.ndarray       # model error ε (nv; zeros: nominal model)


class ControlOutputBuffers(NamedTuple):
    """Where the step writes its torques and planned forces."""

    u_ff: np.ndarray          # feedforward torque (n_j) [Nm]
    u_lin: np.ndarray         # feedback-linearisation torque (n_j) [Nm]
    forces: np.ndarray        # planned contact forces (n_feet × 3) [N], world frame, zero for swing feet


class StepResult(NamedTuple):
    """What `control_step` returns besides the output buffers."""

    flags: int                # STATE_NON_FINITE | REFERENCE_NON_FINITE | EPSILON_REJECTED
    status: int               # QP_SOLVED or the QP's failure (solve_feedforward)
    iterations: int           # proxsuite iterations
    unrealizable: float       # dropped part of eq. (19)'s right-hand side (qp.FeedforwardProblem)
    worst: float              # largest constraint violation of the QP answer


@njit(cache=True)
def control_step(work: ControlWorkspace, par: ControlParameters, inp: ControlInput,
                 out: ControlOutputBuffers) -> StepResult:
    """One step of ciml_control.controller.IdController.compute in one compiled call
    (work and par: IdController.workspace / .parameters; the same records the compiled
    closed loop, ciml_sim.joint_loop.closed_loop, passes):

    1. the nominal terms at the reference (qᵈ, q̇ᵈ) (cached by `work.key`, see desired_terms);
    2. the feedforward QP of eq. (18–21) with ε (zeros if ε is not finite), solved and
       checked (solve_feedforward) → out.u_ff and the planned contact forces out.forces;
    3. the feedback linearisation of eq. (24) at the measured state (the core's Pinocchio
       pass and difference) → out.u_lin, clipped with u_ff to the limits (clip_feedback)
       when the QP was solved; unclipped otherwise (the caller makes the fallback u_ff).

    Its specification is ciml_control.specification (the same equations in numpy,
    test_specification asserts the torques agree). With STATE_NON_FINITE or
    REFERENCE_NON_FINITE in the result's flags nothing else was computed."""
    fns, dyn_meas, limits = work.functions, work.dyn_meas, par.limits
    q, v, contacts, ref_q, ref_v, ref_a = inp.q, inp.v, inp.contacts, inp.ref_q, inp.ref_v, inp.ref_a
    ref_contacts, epsilon = inp.ref_contacts, inp.epsilon
    u_ff, u_lin, forces = out.u_ff, out.u_lin, out.forces
    if not (all_finite(q) and all_finite(v)):
        return StepResult(STATE_NON_FINITE, QP_SOLVED, 0, 0.0, 0.0)
    if not (all_finite(ref_q) and all_finite(ref_v) and all_finite(ref_a)):
        return StepResult(REFERENCE_NON_FINITE, QP_SOLVED, 0, 0.0, 0.0)
    flags = 0
    eps = epsilon
    if not all_finite(epsilon):
        flags |= EPSILON_REJECTED
        eps = np.zeros(epsilon.shape[0])
    nv = v.shape[0]
    desired_terms(fns, work.dyn_des, ref_q, ref_v, work.key, work.M_des, work.h_des, work.J_des)
    A, b, unrealizable, lam0, G, C, c_u, _, rhs = feedforward_matrices(
        work.M_des, work.h_des, work.J_des, ref_contacts, ref_a, eps, par.cone, par.f_min, par.rank_tol)
    lower = np.full(C.shape[0], -INFINITY)
    status, u, lam, iterations, worst = solve_feedforward(fns, work.qp, par.H, par.g, A, b, C, lower, c_u, -limits,
                                                          limits, lam0, G, rhs, par.qp_tolerance)
    forces[:] = 0.0
    u_ff[:] = 0.0
    if status == QP_SOLVED:
        u_ff[:] = u
        c = 0
        for f in range(forces.shape[0]):
            if ref_contacts[f]:
                for a in range(3):
                    forces[f, a] = lam[3 * c + a]
                c += 1
    # feedback linearisation at the measured state, eq. (24): q̈_fb = −K_d ė − K_p e
    e = np.empty(nv)
    ccall(fns[DIFFERENCE], (dyn_meas, ref_q.ctypes.data, q.ctypes.data, e.ctypes.data))
    qdd_fb = np.empty(nv)
    for i in range(nv):
        qdd_fb[i] = -par.kd_lin[i] * (v[i] - ref_v[i]) - par.kp_lin[i] * e[i]
    M_meas, J_meas = work.M_meas, work.J_meas
    ccall(fns[TERMS], (dyn_meas, q.ctypes.data, v.ctypes.data, M_meas.ctypes.data, work.h_meas.ctypes.data,
                      J_meas.ctypes.data))
    u_lin[:] = projected_pinv_apply(M_meas, J_meas, contacts if par.feedback_measured else ref_contacts, qdd_fb,
                                    par.feedback_rank_tol)
    if status == QP_SOLVED:
        clip_feedback(u_ff, u_lin, limits)
    return StepResult(flags, status, iterations, unrealizable, worst)


@njit(cache=True)
def control_step_arrays(functions, dyn_des, dyn_meas, qp, key, M_des, h_des, J_des, M_meas, h_meas, J_meas,
                        H, g, limits, cone, f_min, rank_tol, qp_tolerance, kp_lin, kd_lin, feedback_rank_tol,
                        feedback_measured, q, v, contacts, ref_q, ref_v, ref_a, ref_contacts, epsilon, u_ff, u_lin,
                        forces):
    """`control_step` called from Python (IdController.compute): the fields of its records
    ControlWorkspace, ControlParameters, ControlInput and ControlOutputBuffers as arguments,
    in that order and their field order (the caller passes *workspace, *parameters, …);
    returns StepResult's fields as a plain tuple.

    Why not the records themselves: numba types a named-tuple argument in Python on every
    call from Python, arrays in C — measured +5 µs on the ~120 µs step (ciml bench
    id_controller_step). Inside compiled code the records cost nothing, so compiled callers
    (ciml_sim.joint_loop.closed_loop) pass them."""
    r = control_step(
        ControlWorkspace(functions, dyn_des, dyn_meas, qp, key, M_des, h_des, J_des, M_meas, h_meas, J_meas),
        ControlParameters(H, g, limits, cone, f_min, rank_tol, qp_tolerance, kp_lin, kd_lin, feedback_rank_tol,
                          feedback_measured),
        ControlInput(q, v, contacts, ref_q, ref_v, ref_a, ref_contacts, epsilon),
        ControlOutputBuffers(u_ff, u_lin, forces))
    return r.flags, r.status, r.iterations, r.unrealizable, r.worst
