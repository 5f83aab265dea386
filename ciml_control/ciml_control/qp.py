"""Feedforward inverse-dynamics QP (paper eq. 18–21; Righetti et al., IJRR 2013): the
Python interface to the compiled QP the controller runs.

The specification of the controller is ciml_control.specification (eq. 18–24 in numpy; the
compiled path is tested against it in test_specification). This module does not restate
it: `build_feedforward_qp` returns the very matrices of the compiled step
(compiled.feedforward_qp.feedforward_matrices) and `FeedforwardQP.solve` runs its solve
(compiled.feedforward_qp.solve_feedforward), for tests and tools that want the problem as
data; the product path (IdController.compute → compiled.control_step) calls them directly. The
constants here (DEFAULT_MU, DEFAULT_F_MIN, RANK_TOL, friction_cone_matrix) are the
controller's.

With the model error ε (eq. 17) the rigid-body dynamics at the desired state read

    M q̈ᵈ + h + ε = Sᵀ u + J_cᵀ λ.

QR of the contact Jacobian, J_cᵀ = [Q_c Q_u] [R; 0], splits them into

    Q_uᵀ Sᵀ u = Q_uᵀ (M q̈ᵈ + h + ε)                         (unconstrained dynamics, eq. 19)
    λ = R⁻¹ Q_cᵀ (M q̈ᵈ + h + ε − Sᵀ u)                      (contact forces, eq. 20)

and the QP over the joint torques u (eq. 18–21) is

    min ½ uᵀ W_u u   s.t.  the equality above,
                           λ_z ≥ f_min, octagon friction cone |f_t| ≤ μ f_z (μ = 0.5),
                           −τ_max ≤ u ≤ τ_max (URDF effort limits),

with λ affine in u, so friction cone and unilaterality are linear inequalities in u.
All terms are evaluated at the desired trajectory and the reference contact schedule.

Rank: with two contacts on a line (a trot's diagonal pair) the base rotation about that
line moves neither foot nor any joint, so one row of Q_uᵀ Sᵀ is zero: no torque can
produce a moment about the support line. That row is a condition on the reference, not
on u; the equality is kept on the row space of Q_uᵀ Sᵀ (an orthonormal change of rows
for every full-rank case, so eq. 19 is unchanged there) and the dropped part of the
right-hand side is reported as `FeedforwardProblem.unrealizable` [N or Nm] — feedback
corrects what the reference asks for but the contacts cannot deliver.

Solving: eq. (19) is eliminated before the solver sees the problem — u = u₀ + N z with
u₀ the equality's minimum-norm solution and N an orthonormal basis of its null space
(compiled.feedforward_qp.eliminate_equality), so proxsuite solves a QP in 12 − rank(Q_uᵀSᵀ)
variables (1 in a trot's two-foot support, 6 in four-foot support) with inequalities only; the
answer is then checked against every constraint of the problem above.

`build_feedforward_qp` only builds matrices (tested without a solver);
`FeedforwardQP.solve` solves (proxsuite in the controller's C++ core, the controller's own
compiled path) and raises `QPFailedError` (carrying the problem) instead of returning a
torque when the solve fails or the answer violates a constraint. The small dense algebra
runs compiled (ciml_control.compiled); this module keeps the interfaces.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import proxsuite

from ciml_learning.core.errors import CimlError

from . import native
from .compiled import contact_space
from .compiled.feedforward_qp import (
    INFINITY,
    QP_EXCEPTION,
    QP_NON_FINITE,
    QP_SOLVED,
    QP_VIOLATION,
    feedforward_matrices,
    max_violation,
    solve_feedforward,
)
from .compiled.linalg import arg

DEFAULT_MU = 0.5
"""Friction coefficient of the cone (paper §IV)."""
DEFAULT_F_MIN = 5.0
"""[N] smallest normal force of a stance foot (keeps stance feet loaded)."""
RANK_TOL = 1e-9
"""Relative eigenvalue tolerance of the rank test of Q_uᵀSᵀ (contact_decomposition)."""


class QPFailedError(CimlError):
    """The feedforward QP has no (valid) solution; `.problem` holds the matrices."""

    def __init__(self, message: str, problem: "FeedforwardProblem | None" = None, status: str = "") -> None:
        super().__init__(message)
        self.problem = problem
        self.status = status


def friction_cone_matrix(mu: float = DEFAULT_MU) -> np.ndarray:
    """Rows F (9 × 3) with F f ≤ (0, …, 0, −f_min): 8 facets of the octagon inscribed in the
    cone ‖f_t‖ ≤ μ f_z (cos θ f_x + sin θ f_y ≤ μ cos(π/8) f_z, θ = kπ/4) and −f_z ≤ −f_min."""
    mu_in = mu * math.cos(math.pi / 8)
    rows = [[math.cos(k * math.pi / 4), math.sin(k * math.pi / 4), -mu_in] for k in range(8)]
    rows.append([0.0, 0.0, -1.0])
    return np.array(rows)


@lru_cache(maxsize=64)
def _cone(mu: float) -> np.ndarray:
    return friction_cone_matrix(mu)  # private (never handed out): writable, as the kernels take it


@lru_cache(maxsize=64)
def _constant(kind: str, n: int) -> np.ndarray:
    """Read-only constants shared by all problems of a size: W_u = I, g = 0, l = −∞."""
    a = {"eye": lambda: np.eye(n), "zeros": lambda: np.zeros(n), "minus_inf": lambda: np.full(n, -INFINITY)}[kind]()
    a.setflags(write=False)
    return a


@dataclass
class ContactDecomposition:
    """QR of the contact Jacobian J_cᵀ = [Q_c Q_u][R; 0] and, when Q_uᵀ Sᵀ is rank
    deficient, an orthonormal basis U_r of its row space (None when it has full row rank)."""

    Q_c: np.ndarray
    Q_u: np.ndarray
    R: np.ndarray
    U_r: np.ndarray | None


def contact_decomposition(foot_jacobians: np.ndarray, contacts: np.ndarray, tol: float = 1e-9) -> ContactDecomposition:
    """QR of J_cᵀ plus the row space of Q_uᵀ Sᵀ.

    Q_uᵀ Sᵀ loses rank exactly along base motions that move no stance foot with the
    joints at rest, n_b ∈ null(J_c,base) (a rotation about the line through two feet,
    any base motion without contacts): then w = Q_uᵀ [n_b; 0] satisfies wᵀ Q_uᵀ Sᵀ = 0.
    U_r spans the orthogonal complement of those w (one Householder reflection when
    there is one such w, the common two-feet case). Computed by
    ciml_control.compiled.contact_space.contact_decomposition.
    """
    Q_c, Q_u, R, U_r, has_ur = contact_space.contact_decomposition(
        arg(foot_jacobians), arg(contacts, np.bool_), float(tol))
    return ContactDecomposition(Q_c, Q_u, R, U_r if has_ur else None)


@dataclass
class FeedforwardProblem:
    """Matrices of the QP in u: min ½uᵀHu + gᵀu, A u = b, l ≤ C u ≤ c_u, lb ≤ u ≤ ub.

    Contact forces of a torque vector: λ = lam0 − G u (3 per stance foot, world frame).
    """

    H: np.ndarray
    g: np.ndarray
    A: np.ndarray
    b: np.ndarray
    C: np.ndarray
    l: np.ndarray
    c_u: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    lam0: np.ndarray
    G: np.ndarray
    contacts: np.ndarray
    Q_u: np.ndarray
    rhs: np.ndarray              # M q̈ᵈ + h + ε (nv)
    unrealizable: float          # norm of the dropped (rank-deficient) part of Q_uᵀ rhs

    @property
    def n_contacts(self) -> int:
        return int(np.count_nonzero(self.contacts))

    def contact_forces(self, u: np.ndarray) -> np.ndarray:
        """λ (n_contacts × 3) for torques u, eq. (20)."""
        return (self.lam0 - self.G @ u).reshape(-1, 3)

    def violation(self, u: np.ndarray) -> float:
        """Largest violation of any constraint at u [N, Nm] (0 if feasible, NaN for NaN)."""
        return float(max_violation(arg(self.A), arg(self.b), arg(self.C), arg(self.l), arg(self.c_u),
                                           arg(self.lb), arg(self.ub), arg(u)))


def build_feedforward_qp(
    M: np.ndarray,
    h: np.ndarray,
    foot_jacobians: np.ndarray,
    contacts: np.ndarray,
    qdd_des: np.ndarray,
    epsilon: np.ndarray,
    torque_limits: np.ndarray,
    mu: float = DEFAULT_MU,
    f_min: float = DEFAULT_F_MIN,
    W_u: np.ndarray | None = None,
    rank_tol: float = RANK_TOL,
) -> FeedforwardProblem:
    """Build the QP of eq. (18–21) at one desired state (no solver involved).

    M (nv×nv), h (nv): nominal model at (qᵈ, q̇ᵈ); foot_jacobians (n_feet×3×nv, world-aligned
    linear); contacts (n_feet,) the reference contact schedule; qdd_des (nv); epsilon (nv) the
    model error of eq. (17) (zeros for the nominal model); torque_limits (n_j) [Nm].
    """
    nv = M.shape[0]
    nj = nv - 6
    contacts = np.array(contacts, dtype=np.bool_)  # a copy: the problem keeps it
    A, b, unrealizable, lam0, G, C, c_u, Q_u, rhs = feedforward_matrices(
        arg(M), arg(h), arg(foot_jacobians), contacts, arg(qdd_des), arg(epsilon), arg(_cone(float(mu))),
        float(f_min), float(rank_tol))
    H = _constant("eye", nj) if W_u is None else np.asarray(W_u, float)
    limits = np.asarray(torque_limits, float)
    return FeedforwardProblem(H=H, g=_constant("zeros", nj), A=A, b=b, C=C, l=_constant("minus_inf", len(c_u)),
                              c_u=c_u, lb=-limits, ub=limits.copy(), lam0=lam0, G=G, contacts=contacts, Q_u=Q_u,
                              rhs=rhs, unrealizable=float(unrealizable))


@dataclass
class FeedforwardSolution:
    u: np.ndarray                 # joint torques (n_j) [Nm]
    contact_forces: np.ndarray    # λ (n_contacts × 3) [N], world frame
    iterations: int
    problem: FeedforwardProblem


class FeedforwardQP:
    """proxsuite dense QP for eq. (18–21), solved in the controller's C++ core
    (ciml_control.native; the same compiled path as the controller's step,
    compiled.feedforward_qp.solve_feedforward).

    One solver per problem size is kept and updated in place (a trot alternates two- and
    four-foot support, each keeps its own); every solve starts from proxsuite's
    equality-constrained initial guess, not from the previous answer (with the full QP over
    u that took fewer iterations than a warm start, to the same answer; a stale warm start
    cannot stall it).
    """

    def __init__(self, eps_abs: float = 1e-9, max_iter: int = 200, tolerance: float = 1e-6) -> None:
        self.eps_abs = eps_abs
        self.max_iter = max_iter
        self.tolerance = tolerance
        self._solvers = native.QpSolvers(eps_abs, max_iter)  # len(): how many sizes are kept
        self._functions = native.function_table()

    def solve(self, p: FeedforwardProblem) -> FeedforwardSolution:
        """Solve; raise QPFailedError (with the problem) if no valid torque is found."""
        status, u, lam, iterations, worst = solve_feedforward(
            self._functions, self._solvers.handle, arg(p.H), arg(p.g), arg(p.A), arg(p.b), arg(p.C), arg(p.l),
            arg(p.c_u), arg(p.lb), arg(p.ub), arg(p.lam0), arg(p.G), arg(p.rhs), self.tolerance)
        if status != QP_SOLVED:
            raise QPFailedError(failure_message(status, worst, p.n_contacts), p, status_name(status))
        return FeedforwardSolution(u=u, contact_forces=lam.reshape(-1, 3), iterations=int(iterations), problem=p)


_PROXSUITE_STATUS = {v.value + 1: k for k, v in proxsuite.proxqp.QPSolverOutput.__members__.items()}


def status_name(status: int) -> str:
    """Name of a compiled.feedforward_qp.solve_feedforward status."""
    return {QP_NON_FINITE: "non_finite", QP_VIOLATION: "violation",
            QP_EXCEPTION: "exception"}.get(status) or _PROXSUITE_STATUS.get(status, str(status))


def failure_message(status: int, worst: float, n_contacts: int) -> str:
    """One line on why the QP gave no torque."""
    if status == QP_NON_FINITE:
        return "feedforward QP: non-finite problem data"
    if status == QP_VIOLATION:
        return f"feedforward QP answer violates its constraints by {worst:.3g}"
    return f"feedforward QP not solved ({status_name(status)}, {n_contacts} contacts)"
