"""Null-space projection and the contact-invariant basis (paper §II-III).

    P_c = I − J_c⁺ J_c           projector onto the null space of the contact constraints,
                                 P_c J_cᵀ = 0 (Aghili 2005), so λ_c drops out of eq. (3).
    J'ᵀ = [J_0ᵀ, J_1ᵀ, …]        contact-invariant basis, J_0 = [I_6, 0], J_i the linear
                                 foot Jacobians; Φ̃ = J'ᵀ Φ̃'  (eq. 8).

The per-sample linear algebra of J' and of the leg coupling runs in the compiled core
(core.batch_dynamics; numpy's stacked 3 × 3 routines cost more in their wrappers than in the work).
"""
from __future__ import annotations

import numpy as np

from ciml_learning.core.batch_dynamics import BatchCoreError, address, check, library

DEFAULT_GAMMA = 0.02
"""Smallest singular value [m/rad] kept in a leg's joint block ∂p_foot/∂q_leg.

HyQ's leg blocks have singular values of 0.1–0.6 m/rad away from a straight knee, so
the basis is exact there; at a straight knee the smallest one goes to zero and is
clamped to γ (paper §VI regularises the same block with γI₃), which bounds the
foot entries of Φ̃' at |Φ̃| / γ instead of letting them diverge. The same clamping
makes the separation of a *stance* leg's entries approximate while that leg is
near-singular (its regularised basis columns then differ slightly from J_cᵀ).
"""


def contact_jacobian(foot_jacobians: np.ndarray, contacts: np.ndarray) -> np.ndarray:
    """Stack the linear Jacobians of the feet in contact: J_c (3·n_c × nv)."""
    contacts = np.asarray(contacts, dtype=bool)
    nv = foot_jacobians.shape[-1]
    if not contacts.any():
        return np.zeros((0, nv))
    return foot_jacobians[contacts].reshape(-1, nv)


def projector(J_c: np.ndarray, rcond: float = 1e-10) -> np.ndarray:
    """P_c = I − J_c⁺ J_c (nv × nv), the orthogonal projector onto null(J_c)."""
    nv = J_c.shape[1]
    if J_c.shape[0] == 0:
        return np.eye(nv)
    return np.eye(nv) - np.linalg.pinv(J_c, rcond=rcond) @ J_c


def leg_joint_indices(leg_joints: tuple[tuple[int, ...], ...]) -> np.ndarray:
    """The feet's leg joints (n_feet × 3, int64), each foot's three joints as indices into the
    robot's joints: the core's layout. Foot i owns rows 6+3i … 8+3i of J'."""
    legs = np.asarray(leg_joints, dtype=np.int64)
    if legs.ndim != 2 or legs.shape[1] != 3:
        raise BatchCoreError(f"the contact-invariant basis needs three joints per leg, got {leg_joints}")
    return np.ascontiguousarray(legs)


def require_square_basis(n_feet: int, nv: int) -> None:
    """J' is square (eq. 8, 11) only for a floating base and three joints per foot, nothing else:
    an extra joint (an arm, a spine) is refused, not solved with a truncated basis."""
    if nv != 6 + 3 * n_feet:
        raise BatchCoreError(f"{nv} velocity coordinates are not a floating base and three joints for each "
                             f"of {n_feet} feet: the contact-invariant basis J' needs exactly that")


def contact_invariant_bases(
    foot_jacobians: np.ndarray, leg_joints: tuple[tuple[int, ...], ...], gamma: float = DEFAULT_GAMMA
) -> np.ndarray:
    """J' (N × nv × nv) for a batch of foot Jacobians (N × n_feet × 3 × nv), eq. (8).

    J' = [J_0; J_1; …; J_nf] is block lower-triangular with I₆ in the base block, so it
    is invertible iff every leg's joint block B_i = ∂p_i/∂q_leg,i is. Singular values
    of B_i below `gamma` are raised to `gamma` (exact wherever σ_min(B_i) ≥ γ).
    """
    jac = np.ascontiguousarray(foot_jacobians, dtype=float)
    n, n_feet, three, nv = jac.shape
    legs = leg_joint_indices(leg_joints)
    if three != 3 or len(legs) != n_feet:
        raise BatchCoreError(f"foot Jacobians {jac.shape} do not match {len(legs)} legs")
    require_square_basis(n_feet, nv)
    basis = np.empty((n, nv, nv))
    check(library().ciml_contact_invariant_bases(n, n_feet, nv, address(jac), address(legs), float(gamma),
                                                 address(basis)), "contact_invariant_bases")
    return basis


def contact_invariant_basis(
    foot_jacobians: np.ndarray, leg_joints: tuple[tuple[int, ...], ...], gamma: float = DEFAULT_GAMMA
) -> np.ndarray:
    """J' (nv × nv) of one sample; see contact_invariant_bases."""
    return contact_invariant_bases(foot_jacobians[None], leg_joints, gamma)[0]


def leg_coupling(basis: np.ndarray, leg_joints: tuple[tuple[int, ...], ...]) -> np.ndarray:
    """C (N × 6 × n_j): how each leg joint's rigid-body error reaches the base rows of Φ̃'.

    With B_i = ∂p_i/∂q_leg,i (the leg block of J', regularised) and J_i,base the base columns
    of foot i's rows, a joint-space error e_i of leg i has foot entries φ_i = B_i⁻ᵀ e_i and
    contributes J_i,baseᵀ φ_i = C_i e_i to the base rows of J'ᵀΦ̃' (eq. 8): C_i = J_i,baseᵀ B_i⁻ᵀ.
    C_i is invariant to the base's yaw (both blocks rotate with it).
    """
    basis = np.ascontiguousarray(basis, dtype=float)
    n, nv, _ = basis.shape
    legs = leg_joint_indices(leg_joints)
    C = np.empty((n, 6, nv - 6))
    check(library().ciml_leg_coupling(n, len(legs), nv, address(basis), address(legs), address(C)), "leg_coupling")
    return C


def generalized_rbd_error(basis: np.ndarray, phi_prime: np.ndarray, observed: np.ndarray,
                          leg_joints: tuple[tuple[int, ...], ...]) -> tuple[np.ndarray, np.ndarray]:
    """Φ̃ = J'ᵀ Φ̃' (eq. 8) from the observed entries of Φ̃' (N × nv), and its observed mask.

    Stance feet's entries are unobserved (taken as 0), so the rows of a stance leg's joints are
    unobserved and the base rows hold w' + Σ_swing C_i e_i: the base wrench without the stance
    legs' joint errors, which ModelSet adds back from its leg models (leg_coupling).
    """
    phi = np.where(observed, phi_prime, 0.0)
    generalized = np.einsum("nji,nj->ni", basis, phi)
    mask = np.zeros_like(observed, dtype=bool)
    mask[:, :6] = observed[:, :6]
    for i, leg in enumerate(leg_joints):
        mask[:, 6 + np.asarray(leg)] = observed[:, 6 + 3 * i:7 + 3 * i]
    generalized[~mask] = 0.0
    return generalized, mask
