"""The feedforward QP of eq. (18–21), compiled (numba): its matrices (ciml_control.qp states
the problem), the solve by the C++ core's proxsuite in the coordinates of eq. 19's solutions,
and the polish and check of the answer on the original problem.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..native import QP_DROP, QP_SOLVE, ccall
from .contact_space import contact_decomposition, row_space
from .linalg import all_finite, min_norm_correction, qr_complete

INFINITY = 1e20
"""The QP's bound for 'no bound' (proxsuite takes ±1e20 as infinite)."""
QP_SOLVED = 0
QP_EXCEPTION = -1
QP_NON_FINITE = -2
QP_VIOLATION = -3
"""Status codes of `solve_feedforward` besides proxsuite's QPSolverOutput + 1."""


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
    A, b, unrealizable = row_space(Q_u, rhs, U_r, has_ur)
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
