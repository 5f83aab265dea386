"""The feedback linearisation of eq. (24), compiled (numba), and the clipping of the total
torque to the limits (ciml_control.feedback states the law).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .contact_space import contact_decomposition, row_space
from .linalg import min_norm_apply


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
    A, y, _ = row_space(Q_u, Mq, U_r, has_ur)
    return min_norm_apply(A, y)


@njit(cache=True)
def clip_feedback(u_ff, u_lin, limits) -> None:
    """u_lin ← clip(u_ff + u_lin, ±limits) − u_ff: the total within the torque limits,
    the clipping taken from the linearisation part."""
    for j in range(u_ff.shape[0]):
        t = min(max(u_ff[j] + u_lin[j], -limits[j]), limits[j])
        u_lin[j] = t - u_ff[j]
