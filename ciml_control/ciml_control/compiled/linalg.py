"""Small dense linear algebra of the control step, compiled (numba).

The controller's matrices are tiny (18 × 18 at most); numpy spends far more time in
its Python wrappers than in arithmetic on them (an `np.linalg.qr(..., "complete")`
takes ~20 µs for 18 × 12). These kernels do the same algebra in one compiled call
each, with explicit loops (no BLAS threads involved). `qr_complete` follows LAPACK's
conventions (dgeqr2/dorg2r: β = −sign(α)‖x‖, Q = H₁⋯H_n), so Q and R equal numpy's
`np.linalg.qr(A, "complete")` to rounding.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit


def arg(x, dtype=np.float64) -> np.ndarray:
    """x as a C-contiguous array of dtype (no copy if it is one already). numba compiles
    one specialisation per argument layout (and per read-only flag): the control path
    passes writable C arrays."""
    return np.ascontiguousarray(x, dtype=dtype)


@njit(cache=True)
def all_finite(a: np.ndarray) -> bool:
    for x in a.flat:
        if not np.isfinite(x):
            return False
    return True


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
def solve_small(A: np.ndarray, b: np.ndarray) -> np.ndarray:
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
