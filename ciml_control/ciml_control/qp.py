"""Feedforward inverse-dynamics QP (paper eq. 18–21; Righetti et al., IJRR 2013).

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

`build_feedforward_qp` only builds matrices (tested without a solver);
`FeedforwardQP.solve` solves with proxsuite, keeps one warm-started solver per problem
size, and raises `QPFailedError` (carrying the problem) instead of returning a torque
when the solve fails or the answer violates a constraint.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from functools import lru_cache

import numpy as np
import proxsuite

from ciml_learning.errors import CimlError

DEFAULT_MU = 0.5
"""Friction coefficient of the cone (paper §IV)."""
DEFAULT_F_MIN = 5.0
"""[N] smallest normal force of a stance foot (keeps stance feet loaded)."""
INFINITY = 1e20


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
def _block_cone(mu: float, n_contacts: int) -> np.ndarray:
    F = np.kron(np.eye(n_contacts), friction_cone_matrix(mu))
    F.setflags(write=False)
    return F


@lru_cache(maxsize=64)
def _cone_bound(f_min: float, n_contacts: int) -> np.ndarray:
    d = np.tile(np.r_[np.zeros(8), -f_min], n_contacts)
    d.setflags(write=False)
    return d


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
    U_r spans the orthogonal complement of those w.
    """
    nv = foot_jacobians.shape[-1]
    contacts = np.asarray(contacts, dtype=bool)
    Jc = foot_jacobians[contacts].reshape(-1, nv)
    nc3 = Jc.shape[0]
    if nc3:
        Q, R = np.linalg.qr(Jc.T, mode="complete")
        Q_c, Q_u, R = Q[:, :nc3], Q[:, nc3:], R[:nc3]
        Jb = Jc[:, :6]
        w, V = np.linalg.eigh(Jb.T @ Jb)
        Nb = V[:, w < tol * max(w[-1], 1.0)]
    else:
        Q_c, Q_u, R = np.zeros((nv, 0)), np.eye(nv), np.zeros((0, 0))
        Nb = np.eye(6)
    if Nb.shape[1] == 0:
        return ContactDecomposition(Q_c, Q_u, R, None)
    W = Q_u[:6].T @ Nb                                      # Q_uᵀ [n_b; 0], orthonormal columns
    if W.shape[1] == 1:  # the common case (two feet): complement from one Householder reflection
        w = W[:, 0]
        v = w.copy()
        v[0] += 1.0 if w[0] >= 0 else -1.0
        H = np.eye(len(w)) - (2.0 / (v @ v)) * np.outer(v, v)  # H e₁ = ∓w
        return ContactDecomposition(Q_c, Q_u, R, H[:, 1:])
    Qw, _ = np.linalg.qr(W, mode="complete")
    return ContactDecomposition(Q_c, Q_u, R, Qw[:, Nb.shape[1]:])


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
        """Largest violation of any constraint at u [N, Nm] (0 if feasible)."""
        worst = float(np.max(np.abs(self.A @ u - self.b))) if len(self.b) else 0.0
        if len(self.l):
            cu = self.C @ u
            worst = max(worst, float(np.max(np.maximum(self.l - cu, cu - self.c_u))))
        return max(worst, float(np.max(np.maximum(self.lb - u, u - self.ub))))


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
    rank_tol: float = 1e-9,
) -> FeedforwardProblem:
    """Build the QP of eq. (18–21) at one desired state (no solver involved).

    M (nv×nv), h (nv): nominal model at (qᵈ, q̇ᵈ); foot_jacobians (n_feet×3×nv, world-aligned
    linear); contacts (n_feet,) the reference contact schedule; qdd_des (nv); epsilon (nv) the
    model error of eq. (17) (zeros for the nominal model); torque_limits (n_j) [Nm].
    """
    nv = M.shape[0]
    nj = nv - 6
    contacts = np.asarray(contacts, dtype=bool)
    rhs = M @ qdd_des + h + epsilon
    dec = contact_decomposition(foot_jacobians, contacts, rank_tol)
    Q_c, Q_u, R, U_r = dec.Q_c, dec.Q_u, dec.R, dec.U_r
    nc3 = Q_c.shape[1]
    # equality Q_uᵀ Sᵀ u = Q_uᵀ rhs, kept on the row space of Q_uᵀ Sᵀ (module docstring)
    A_full = Q_u[6:].T
    b_full = Q_u.T @ rhs
    if U_r is None:
        A, b, unrealizable = A_full, b_full, 0.0
    else:
        A, b = U_r.T @ A_full, U_r.T @ b_full
        unrealizable = float(np.linalg.norm(b_full - U_r @ b))
    # contact forces λ = R⁻¹ Q_cᵀ (rhs − Sᵀ u) = lam0 − G u
    if nc3:
        sol = np.linalg.solve(R, np.column_stack([Q_c.T @ rhs, Q_c[6:].T]))  # (numpy: scipy's BLAS threads spin on tiny solves)
        lam0, G = sol[:, 0], sol[:, 1:]
        n_c = nc3 // 3
        Fb = _block_cone(mu, n_c)                              # (9 n_c × 3 n_c)
        d = _cone_bound(f_min, n_c)                             # Fb λ ≤ d
        C = -Fb @ G                                           # Fb (lam0 − G u) ≤ d
        c_u = d - Fb @ lam0
        l = np.full(len(c_u), -INFINITY)
    else:
        lam0, G = np.zeros(0), np.zeros((0, nj))
        C, l, c_u = np.zeros((0, nj)), np.zeros(0), np.zeros(0)
    H = np.eye(nj) if W_u is None else np.asarray(W_u, float)
    return FeedforwardProblem(H=H, g=np.zeros(nj), A=A, b=b, C=C, l=l, c_u=c_u,
                              lb=-np.asarray(torque_limits, float), ub=np.asarray(torque_limits, float),
                              lam0=lam0, G=G, contacts=contacts.copy(), Q_u=Q_u, rhs=rhs,
                              unrealizable=unrealizable)


@dataclass
class FeedforwardSolution:
    u: np.ndarray                 # joint torques (n_j) [Nm]
    contact_forces: np.ndarray    # λ (n_contacts × 3) [N], world frame
    iterations: int
    problem: FeedforwardProblem


class FeedforwardQP:
    """proxsuite dense QP for eq. (18–21), one warm-started solver per problem size.

    The solver of a size is created once and updated afterwards (warm start from its
    previous result); a trot alternates two- and four-foot support, each keeps its own.
    """

    def __init__(self, eps_abs: float = 1e-9, max_iter: int = 200, tolerance: float = 1e-6) -> None:
        self.eps_abs = eps_abs
        self.max_iter = max_iter
        self.tolerance = tolerance
        self._solvers: dict[tuple[int, int, int], tuple] = {}  # size → (solver, H, g)

    def _solver(self, p: FeedforwardProblem):
        nj = p.H.shape[0]
        key = (nj, len(p.b), len(p.l))
        entry = self._solvers.get(key)
        if entry is None:
            qp = proxsuite.proxqp.dense.QP(nj, len(p.b), len(p.l), True)
            qp.settings.eps_abs = self.eps_abs
            qp.settings.eps_rel = 0.0
            qp.settings.max_iter = self.max_iter
            qp.settings.verbose = False
            qp.settings.initial_guess = proxsuite.proxqp.InitialGuess.EQUALITY_CONSTRAINED_INITIAL_GUESS
            qp.init(p.H, p.g, p.A, p.b, p.C, p.l, p.c_u, p.lb, p.ub)
            self._solvers[key] = (qp, p.H.copy(), p.g.copy())
            return qp, True
        qp, H, g = entry
        qp.settings.initial_guess = proxsuite.proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
        same_cost = np.array_equal(H, p.H) and np.array_equal(g, p.g)
        qp.update(None if same_cost else p.H, None if same_cost else p.g, p.A, p.b, p.C, p.l, p.c_u, p.lb, p.ub)
        if not same_cost:
            self._solvers[key] = (qp, p.H.copy(), p.g.copy())
        return qp, False

    def solve(self, p: FeedforwardProblem) -> FeedforwardSolution:
        """Solve; raise QPFailedError (with the problem) if no valid torque is found."""
        if not (np.isfinite(p.rhs).all() and np.isfinite(p.C).all() and np.isfinite(p.c_u).all()
                and np.isfinite(p.A).all() and np.isfinite(p.b).all()):
            raise QPFailedError("feedforward QP: non-finite problem data", p, "non_finite")
        qp, fresh = self._solver(p)
        qp.solve()
        status = qp.results.info.status
        if status != proxsuite.proxqp.QPSolverOutput.PROXQP_SOLVED and not fresh:
            # a stale warm start can stall: retry once from a cold start
            qp.init(p.H, p.g, p.A, p.b, p.C, p.l, p.c_u, p.lb, p.ub)
            qp.settings.initial_guess = proxsuite.proxqp.InitialGuess.EQUALITY_CONSTRAINED_INITIAL_GUESS
            qp.solve()
            status = qp.results.info.status
        if status != proxsuite.proxqp.QPSolverOutput.PROXQP_SOLVED:
            # drop the solver: its state after a failure is no good warm start
            self._solvers.pop((p.H.shape[0], len(p.b), len(p.l)), None)
            raise QPFailedError(f"feedforward QP not solved ({status.name}, {p.n_contacts} contacts)", p, status.name)
        u = np.array(qp.results.x, dtype=float)
        # remove the solver's residual from the equality (min-norm correction, ~eps_abs)
        if len(p.b):
            u = u - p.A.T @ np.linalg.solve(p.A @ p.A.T, p.A @ u - p.b)  # A has full row rank
        scale = max(1.0, float(np.max(np.abs(p.b))) if len(p.b) else 1.0, float(np.max(np.abs(p.c_u))) if len(p.c_u) else 1.0)
        worst = p.violation(u)
        if not np.all(np.isfinite(u)) or worst > self.tolerance * scale:
            self._solvers.pop((p.H.shape[0], len(p.b), len(p.l)), None)
            raise QPFailedError(f"feedforward QP answer violates its constraints by {worst:.3g}", p, "violation")
        return FeedforwardSolution(u=u, contact_forces=p.contact_forces(u), iterations=int(qp.results.info.iter), problem=p)
