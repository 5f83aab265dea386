"""The contact space of eq. (19), compiled (numba): the stance feet's stacked Jacobian, its QR
J_cᵀ = [Q_c Q_u][R; 0] (Q_uᵀ removes the contact forces from the dynamics) and the row space
of Q_uᵀSᵀ when that is rank deficient (see ciml_control.qp). The feedforward QP and the feedback
linearisation both start from it.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .linalg import qr_complete


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
def row_space(Q_u: np.ndarray, x: np.ndarray, U_r: np.ndarray, has_ur: bool):
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
