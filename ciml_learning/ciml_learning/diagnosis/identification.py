"""Which effect causes the gap: noise-normalised, sign-constrained least squares and greedy
forward selection of the smallest candidate set that explains the error on held-out data.

Baseline. Every model includes the command-update sampling term (candidates.py: a property of
how the log samples a faster joint loop, not of the robot); "nominal" means nominal model plus
this baseline, and the gap is what remains after it.

Metric. Every output dimension d (18 Φ̃' entries, then one Γ per joint) is divided by its
noise level σ_d, so a dimension with a larger noise floor does not dominate and the gap is
measured in units of what the data can resolve. σ_d is the residual RMS of a fit of *all*
candidate features on the identification data (what no catalogue effect explains), pooled
robustly over dimensions of the same kind (base forces, base torques, each foot axis, joint
actuation): σ_d = clip(σ_d,own, ½ σ_pool, 2 σ_pool) with σ_pool the median of the pool, so an
effect outside the catalogue that hits one joint or leg keeps its size relative to the others.

Selection. Rigid-body candidates explain Φ̃' rows, actuation candidates Γ rows, torque-sensor
candidates both; all compete in one loop, each against its own kind's threshold. Starting from the
baseline, each step refits every current candidate plus one new candidate on the identification
data (inside the physical bounds of bounds.py; proxsuite QP) and measures the normalised residual
on held-out data. The candidate with the largest held-out reduction is accepted if that reduction
is at least MIN_SHARE of its kind's nominal held-out residual (and MIN_NOISE_GAIN of its noise
power), its parameters are not on a physical bound, and it is not negligible (relevance_function: at least
MIN_RELEVANCE of the robot's own forces where it acts); a candidate with fewer parameters
within PARSIMONY of the best wins a near-tie. After each acceptance, swaps of a selected effect
for an unselected one are tried (an effect chosen before the others were modelled may be the
wrong one); at the end, effects on a bound or no longer paying for themselves are dropped.
Finally effects whose parameter is not consistent across contact configurations and bags
(consistency() > MAX_SPREAD) are rejected: a physical effect has one value everywhere, a
stand-in for an effect outside the catalogue does not.

Outside the catalogue. A free position-dependent torque f_j(q_j) per joint (candidates.generic_joint_basis:
a spring, a cable, a gravity-like torque no link mass explains) competes in the
forward steps with its gain discounted by OUT_OF_CATALOGUE_MARGIN: it is chosen only when it
explains clearly more than every catalogue effect, i.e. when the catalogue's best answer at that
joint would be a stand-in. What it explains is reported as unexplained, localised at its joint
(never as an effect); it never enters by a swap and has no consistency check.

Shares. unexplained_share = (held-out residual − noise floor) / (nominal held-out residual − noise
floor) (normalised sums of squares; noise_floor: noise is not an unexplained effect); the explained
part 1 − unexplained_share is split among the effects in proportion to what removing each one
costs on held-out data. An estimate that ends on a non-null physical bound is "not identified".

Uncertainty: parameter_uncertainty (uncertainty.py; docs/DIAGNOSIS.md).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import brentq

from ciml_learning.diagnosis.bounds import physical_violation
from ciml_learning.diagnosis.candidates import Candidate, FeatureLayout
from ciml_learning.diagnosis.features import Grams, Rows
from ciml_learning.effects import EFFECTS, Conversion, effect_type

MIN_SHARE = 0.005
"""Smallest held-out reduction, as a fraction of the nominal normalised residual of the
candidate's kind (Φ̃' or Γ), to accept an effect."""
MIN_NOISE_GAIN = 0.05
"""... and at least this fraction of the noise power (one unit per normalised row)."""
SWAP_MARGIN = 0.2
"""A swap must improve the held-out residual by this fraction of the acceptance threshold."""
PARSIMONY = 0.05
"""A candidate with fewer parameters wins if its reduction is within this fraction of the best's."""
RIDGE = 1e-9
"""Relative ridge on the Jacobi-scaled normal equations (numerical safety only)."""
MIN_PAYLOAD_MASS = 0.1
"""[kg] below this the payload's CoM (and rotational inertia) is not refined."""
MAX_PAYLOAD_LEVER = 1.0
"""[m] a payload sits on the robot: its CoM is at most this far from the base origin."""
SIGMA_FLOOR = 0.01
"""[N or Nm] smallest noise level (sensor resolution): noise-free simulations have none."""
MIN_RELEVANCE = 0.005
"""Smallest size of an effect relative to the robot's own forces where it acts (relevance_function):
a systematic but negligible term (0.5 % of the torque a joint carries) is not named."""
MAX_SPREAD = 0.5
"""Largest relative spread of an effect's parameter across data subsets (consistency())."""
OUT_OF_CATALOGUE_MARGIN = 0.15
"""The out-of-catalogue probe must explain this fraction more than the best catalogue effect."""
MIN_SUBSET_INFORMATION = 0.05
"""Subsets holding less than this fraction of an effect's information are left out of its spread."""
BOOTSTRAP = 100
MAX_EFFECTS = 12
GAP_AT_FLOOR = 0.02
"""A held-out gap above the noise floor smaller than this fraction of the nominal residual is none."""
BIG = 1e20


def bounded_least_squares(H: np.ndarray, c: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """argmin ½θᵀHθ − cᵀθ s.t. lower ≤ θ ≤ upper (proxsuite dense QP, Jacobi-scaled)."""
    import proxsuite

    p = len(c)
    if p == 0:
        return np.zeros(0)
    d = np.sqrt(np.maximum(np.diag(H), 0.0))
    d[d <= 1e-300] = 1.0
    Dinv = 1.0 / d
    Hs = H * np.outer(Dinv, Dinv)
    Hs = 0.5 * (Hs + Hs.T) + RIDGE * np.eye(p)
    gs = -c * Dinv
    lo = np.where(np.isfinite(lower), lower * d, -BIG)
    hi = np.where(np.isfinite(upper), upper * d, BIG)
    unconstrained = np.linalg.solve(Hs, -gs)
    if np.all(unconstrained >= lo) and np.all(unconstrained <= hi):
        return unconstrained * Dinv
    qp = proxsuite.proxqp.dense.QP(p, 0, p)
    qp.settings.eps_abs = 1e-10
    qp.settings.eps_rel = 0.0
    qp.settings.verbose = False
    qp.init(Hs, gs, None, None, np.eye(p), lo, hi)
    qp.solve()
    phi = np.clip(np.asarray(qp.results.x, float), lo, hi)
    return phi * Dinv


@dataclass
class Model:
    """A set of candidates with fitted parameters θ (concatenated in candidate order)."""

    layout: FeatureLayout
    candidates: list[Candidate]
    theta: np.ndarray
    payload_com: np.ndarray | None = None
    lag_scale: dict[str, float] | None = None
    sampling: CommandSampling | None = None  # how the logs sample the command (the lag's reading, lag_time_constant)
    nonlinear: dict[str, float] = field(default_factory=dict)  # candidate label → its non-linear parameter

    def matrix(self) -> np.ndarray:
        rows, A_rows = self.compact_matrix()
        A = np.zeros((self.layout.n_features, A_rows.shape[1]))
        A[rows] = A_rows
        return A

    def compact_matrix(self) -> tuple[np.ndarray, np.ndarray]:
        """(rows, A[rows]): the features some candidate loads, and the model's A there."""
        blocks = [self.layout.block(c, self.payload_com, self.lag_scale, self.nonlinear) for c in self.candidates]
        rows = np.unique(np.concatenate([r for r, _ in blocks])) if blocks else np.zeros(0, int)
        A = np.zeros((len(rows), sum(c.n_params for c in self.candidates)))
        k = 0
        for r, B in blocks:
            A[np.searchsorted(rows, r), k:k + B.shape[1]] = B
            k += B.shape[1]
        return rows, A

    def feature_theta(self) -> np.ndarray:
        """Coefficients on the feature columns (A θ)."""
        return self.matrix() @ self.theta if self.candidates else np.zeros(self.layout.n_features)

    def slices(self) -> list[slice]:
        out, k = [], 0
        for c in self.candidates:
            out.append(slice(k, k + c.n_params))
            k += c.n_params
        return out

    def part(self, cands: list[Candidate]) -> "Model":
        """The same fitted parameters, restricted to some of the candidates (no refit)."""
        sl = self.slices()
        theta = [self.theta[sl[self.candidates.index(c)]] for c in cands]
        return Model(self.layout, list(cands), np.concatenate(theta) if theta else np.zeros(0), self.payload_com,
                     self.lag_scale, self.sampling, {c.label: self.nonlinear[c.label] for c in cands
                                                     if c.label in self.nonlinear})

    def warm_start(self) -> dict[str, Any]:
        """fit_model's `start` from this model: its non-linear parameters and its payload's CoM."""
        payload = _payload(self.candidates)
        extra = {payload.label: self.payload_com} if payload is not None and self.payload_com is not None else {}
        return {**self.nonlinear, **extra}

    def params_of(self, cand: Candidate) -> np.ndarray:
        i = self.candidates.index(cand)
        return self.theta[self.slices()[i]]


def _payload(cands: list[Candidate]) -> Candidate | None:
    return next((k for k in cands if k.type == "payload"), None)


def _bounds(cands: list[Candidate]) -> tuple[np.ndarray, np.ndarray]:
    lo = np.concatenate([np.asarray(c.lower, float) for c in cands]) if cands else np.zeros(0)
    hi = np.concatenate([np.asarray(c.upper, float) for c in cands]) if cands else np.zeros(0)
    return lo, hi


def _nonlinear_range(cand: Candidate) -> tuple[str, float, float] | None:
    """(name, lo, hi) of a candidate's non-linear parameter (EffectType.nonlinear), None for most."""
    t = EFFECTS.get(cand.type)
    return t.nonlinear if t is not None and cand.in_catalogue else None


NONLINEAR_XTOL = 0.005
"""[octaves] resolution of the 1-D search of a non-linear parameter (0.35 %)."""


def _solve(model: Model, G: np.ndarray, c: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """θ of the model's current A (bounded least squares); returns the objective θᵀHθ − 2cᵀθ
    (the training residual up to a constant)."""
    rows, A = model.compact_matrix()  # a candidate loads a few of the ~300 features
    H, g = A.T @ G[np.ix_(rows, rows)] @ A, A.T @ c[rows]
    model.theta = bounded_least_squares(H, g, lo, hi)
    return float(model.theta @ H @ model.theta - 2 * g @ model.theta)


def _search_nonlinear(model: Model, cand: Candidate, G: np.ndarray, c: np.ndarray, lo: np.ndarray,
                      hi: np.ndarray, start: float | None) -> None:
    """Fit a candidate's non-linear parameter p (Stribeck velocity) by a 1-D search over log₂ p, every
    linear parameter refitted at each trial: a scan at half octaves then a bounded Brent search around
    the best (around `start` alone when given: a warm start within half an octave)."""
    from scipy.optimize import minimize_scalar

    _, p_lo, p_hi = _nonlinear_range(cand)  # type: ignore[misc]
    span = float(np.log2(p_hi / p_lo))

    def f(x: float) -> float:
        model.nonlinear[cand.label] = p_lo * 2.0 ** float(np.clip(x, 0.0, span))
        return _solve(model, G, c, lo, hi)

    if start is None:
        grid = np.linspace(0.0, span, int(round(2 * span)) + 1)
        x0 = float(grid[int(np.argmin([f(x) for x in grid]))])
    else:
        x0 = float(np.clip(np.log2(start / p_lo), 0.0, span))
    res = minimize_scalar(f, bounds=(max(0.0, x0 - 0.5), min(span, x0 + 0.5)), method="bounded",
                          options={"xatol": NONLINEAR_XTOL})
    f(float(res.x))


def fit_model(layout: FeatureLayout, cands: list[Candidate], G: np.ndarray, c: np.ndarray,
              refine_payload: int = 3, sampling: CommandSampling | None = None,
              start: dict[str, Any] | None = None) -> Model:
    """Fit the parameters of a candidate set on weighted Grams (G = Σ w_d G_d, c = Σ w_d c_d).

    Two terms are bilinear and refined by refitting (at most refine_payload times, until they change
    by less than REFINE_TOL): a payload's point-mass rotational inertia depends on its CoM; the all-joint
    lag's coefficient on a joint with an identified torque gain is T/g_j. A non-linear parameter
    (Stribeck velocity) is then fitted by a 1-D search (_search_nonlinear). `start`: label → a warm start
    (a non-linear parameter's value, the payload's CoM)."""
    model = Model(layout, list(cands), np.zeros(sum(k.n_params for k in cands)), sampling=sampling)
    if not cands:
        return model
    start = start or {}
    lo, hi = _bounds(model.candidates)
    payload = _payload(cands)
    gains = [k for k in cands if k.type == "torque_gain"]
    coupled = bool(gains) and any(k.type == "actuator_lag" and len(k.joints) > 1 for k in cands)
    refine = refine_payload if (payload is not None or coupled) else 0
    nonlinear = [k for k in cands if _nonlinear_range(k) is not None]
    for k in nonlinear:
        _, p_lo, p_hi = _nonlinear_range(k)  # type: ignore[misc]
        model.nonlinear[k.label] = start.get(k.label) or float(np.sqrt(p_lo * p_hi))
    if payload is not None and start.get(payload.label) is not None:
        model.payload_com = np.asarray(start[payload.label], float)
    for _ in range(1 + refine):
        before = (model.payload_com, model.lag_scale)
        _solve(model, G, c, lo, hi)
        if coupled:
            model.lag_scale = {str(k.joint): float(1.0 - model.params_of(k)[0]) for k in gains}
        if payload is not None:
            p = model.params_of(payload)
            if p[0] < MIN_PAYLOAD_MASS:
                model.payload_com = None
            else:
                com = p[1:4] / p[0]
                n = np.linalg.norm(com)
                model.payload_com = com if n <= MAX_PAYLOAD_LEVER else com * (MAX_PAYLOAD_LEVER / n)
        if _refined(before, (model.payload_com, model.lag_scale)):
            break
    for k in nonlinear:
        _search_nonlinear(model, k, G, c, lo, hi, start.get(k.label))
    return model


REFINE_TOL = 1e-5
"""[m of CoM, or of a lag's 1/g_j] a bilinear term that changes less than this in a refit is refined."""


def _refined(before: tuple, after: tuple) -> bool:
    """The bilinear terms (payload CoM, lag scales) the last fit used are those it gives (within REFINE_TOL)."""
    (com0, lag0), (com1, lag1) = before, after
    if (com0 is None) != (com1 is None) or (lag0 is None) != (lag1 is None):
        return False
    if com0 is not None and np.max(np.abs(com1 - com0)) > REFINE_TOL:
        return False
    return lag0 is None or max(abs(lag1[j] - lag0[j]) for j in lag1) <= REFINE_TOL


def _nonlinear_at_bound(model: Model, cand: Candidate) -> bool:
    """A non-linear parameter at an end of its range (within the search's resolution)."""
    r = _nonlinear_range(cand)
    if r is None or cand.label not in model.nonlinear:
        return False
    x = np.log2(model.nonlinear[cand.label] / r[1])
    return bool(x <= 4 * NONLINEAR_XTOL or x >= np.log2(r[2] / r[1]) - 4 * NONLINEAR_XTOL)


def _at_bound(model: Model, cand: Candidate, rel: float = 1e-6) -> bool:
    """A parameter on a physical bound: the data push the effect beyond what it can be (friction
    below zero, a mass scale to zero, an offset beyond its range) — it does not explain them."""
    th = model.params_of(cand)
    lo, hi = np.asarray(cand.lower), np.asarray(cand.upper)
    tol = rel * np.maximum(np.abs(th), 1.0) + 1e-12
    on = (np.abs(th - lo) <= tol) | (np.abs(th - hi) <= tol)
    kind = EFFECTS.get(cand.type) if cand.in_catalogue else None
    if kind is not None and kind.may_vanish:
        on &= ~np.array([n in kind.may_vanish and b == 0.0 for n, b in zip(cand.param_names, lo)])
    if cand.type == "payload":
        return bool(on[0] or th[0] < MIN_PAYLOAD_MASS or (
            model.payload_com is not None and np.linalg.norm(model.payload_com) >= MAX_PAYLOAD_LEVER * (1 - 1e-9)))
    if on.any() or _nonlinear_at_bound(model, cand):
        return True
    # a converted parameter can leave its range while θ is inside its box (bounds.py)
    return cand.type == "actuator_lag" and physical_violation(cand.type, _physical_of(model, cand)) is not None


def _physical_of(model: Model, cand: Candidate) -> dict:
    """physical_parameters of one candidate (with the torque gain of its joint, which its conversion needs)."""
    part = [c for c in model.candidates if c is cand or (c.type == "torque_gain" and c.joint == cand.joint)]
    return physical_parameters(model.part(part))[part.index(cand)]


def _at_far_bound(model: Model, cand: Candidate) -> bool:
    """On a bound that is not the parameter's null value (0: no effect): "at bound — not identified"."""
    th = model.params_of(cand)
    for t, lo, hi in zip(th, cand.lower, cand.upper):
        for b in (lo, hi):
            if b != 0.0 and _on(t, b):
                return True
    if cand.type == "payload":
        return bool(model.payload_com is not None
                    and np.linalg.norm(model.payload_com) >= MAX_PAYLOAD_LEVER * (1 - 1e-9))
    return _nonlinear_at_bound(model, cand)


def dimension_pools(layout: FeatureLayout) -> list[np.ndarray]:
    """Groups of output dimensions of the same kind (for the pooled noise level)."""
    nf = layout.robot.n_feet
    pools = [np.arange(0, 3), np.arange(3, 6)]
    pools += [6 + 3 * np.arange(nf) + a for a in range(3)]
    n_rbd = 6 + 3 * nf
    pools.append(n_rbd + np.arange(layout.robot.n_joints))
    return pools


def noise_levels(layout: FeatureLayout, g: Grams, fallback: Grams | None = None) -> tuple[np.ndarray, np.ndarray]:
    """σ_d (see module docstring) and the per-dimension residual RMS of the full fit.

    A pool with no identification data at all (e.g. no foot ever swings there) takes the
    nominal RMS of the `fallback` (held-out) data: its nominal error then counts one unit per row."""
    D = len(g.s)
    n = np.maximum(g.n, 1)
    rms_y = np.sqrt(g.s / n)
    w0 = np.where(g.n > 0, 1.0 / np.maximum(rms_y, 1e-9) ** 2, 0.0)
    Gw, cw, _ = g.weighted(w0)
    # the catalogue only: σ is what no catalogue effect explains; without the torque-sensor candidates,
    # whose Φ̃ regressor τ_m carries the torque sensor's noise that is also in Φ̃ (Sᵀτ_m): an in-sample
    # fit with them takes that noise for a model error and σ comes out far too small
    used = np.unique(np.concatenate([np.asarray(c.features) for c in layout.candidates + [layout.baseline]
                                     if c.in_catalogue and c.kind != "sensor"]))
    # nor the columns of a non-linear parameter's grid (Stribeck velocities): together they span a free
    # function of the joint's speed, far more than the one curve of the effect, and would absorb as noise
    # what no catalogue effect explains
    used = np.setdiff1d(used, layout.joint_feature_columns())
    Gw, cw = Gw[np.ix_(used, used)], cw[used]
    # ridge relative to each feature's scale: the full catalogue is collinear (lag per joint and all)
    diag = np.maximum(np.diag(Gw), 1e-300)
    theta = np.zeros(layout.n_features)
    theta[used] = np.linalg.solve(Gw + 1e-6 * np.diag(diag), cw)
    rms_res = np.sqrt(np.maximum(g.ss(theta), 0.0) / n)
    sigma = np.ones(D)
    for pool in dimension_pools(layout):
        obs = pool[g.n[pool] > 0]
        if len(obs) == 0:
            if fallback is not None and (fallback.n[pool] > 0).any():
                fb = pool[fallback.n[pool] > 0]
                sigma[pool] = max(float(np.median(np.sqrt(fallback.s[fb] / fallback.n[fb]))), 2 * SIGMA_FLOOR)
            continue
        med = float(np.median(rms_res[obs]))
        med = max(med, 2 * SIGMA_FLOOR)
        sigma[pool] = np.clip(rms_res[pool], 0.5 * med, 2.0 * med)
    return sigma, rms_res


@dataclass
class Step:
    accepted: str
    gain_share: float
    runner_up: str | None
    runner_up_share: float


@dataclass
class Selection:
    model: Model
    sigma: np.ndarray
    weights: np.ndarray
    nominal_ss: float            # held-out normalised SS, nominal model
    final_ss: float              # held-out normalised SS with the selected effects
    shares: list[float]          # per selected candidate (of the gap above the noise floor)
    steps: list[Step] = field(default_factory=list)
    full_fit_rms: np.ndarray | None = None
    spread: list[float] = field(default_factory=list)           # consistency() of each selected effect
    raw_nominal_ss: float = 0.0                                  # held-out normalised SS without the baseline
    n_baseline: int = 0                                          # model.candidates[:n_baseline] = the baseline
    rejected: list[tuple[str, float]] = field(default_factory=list)  # (label, spread) rejected as inconsistent
    floor_ss: float = 0.0        # held-out normalised SS of the noise floor (noise_floor)
    noise_floor: np.ndarray | None = None  # per dimension [N or Nm] (noise_floor)
    not_identified: list[dict] = field(default_factory=list)  # candidates whose estimate ends on a bound
    fit_weights: np.ndarray | None = None  # the weights the model was fitted with (None: `weights`)

    @property
    def fitted_with(self) -> np.ndarray:
        """The weights of the model's fit (parameter_uncertainty refits with them)."""
        return self.weights if self.fit_weights is None else self.fit_weights

    @property
    def effects(self) -> list[Candidate]:
        return self.model.candidates[self.n_baseline:]

    @property
    def gap_ss(self) -> float:
        """The held-out gap above the noise floor (normalised SS): what effects can explain."""
        return max(self.nominal_ss - self.floor_ss, 0.0)

    @property
    def gap_at_noise_floor(self) -> bool:
        """The nominal held-out error is (almost) all noise: nothing above the floor to explain."""
        return self.gap_ss <= GAP_AT_FLOOR * self.nominal_ss

    @property
    def unexplained_share(self) -> float:
        """Share of the gap *above the noise floor* the selected effects leave (noise is not an effect)."""
        if self.gap_at_noise_floor:
            return 0.0
        return float(np.clip((self.final_ss - self.floor_ss) / self.gap_ss, 0.0, 1.0))

    @property
    def unexplained_share_with_noise(self) -> float:
        """final / nominal held-out residual, noise included (the earlier definition)."""
        return float(self.final_ss / self.nominal_ss) if self.nominal_ss > 0 else 0.0


def _heldout_ss(model: Model, Gh: np.ndarray, ch: np.ndarray, sh: float) -> float:
    t = model.feature_theta()
    return float(sh - 2 * ch @ t + t @ Gh @ t)


def relevance_function(rows: Rows, train: Grams):
    """relevance(model, cand) → the effect's size relative to the robot's own forces: the largest,
    over generalized coordinates, RMS of its generalized force (before eq. 11; Γ for actuation
    and sensor effects) divided by the RMS of the signal there (M q̈ + h on the base, τ on the joints)."""
    lay = rows.layout
    n_rbd_dims = 6 + 3 * lay.robot.n_feet
    n = max(rows.n_raw, 1)
    raw_rms = np.sqrt(np.maximum(rows.raw_signal, 0) / n) if rows.raw_signal is not None else None

    def relevance(model: Model, cand: Candidate) -> float:
        loaded, B = lay.block(cand, model.payload_com, model.lag_scale, model.nonlinear)
        t = np.zeros(lay.n_features)
        t[loaded] = B @ model.params_of(cand)
        if cand.kind == "rbd":
            if rows.raw_G is None:
                return np.inf
            nz = np.flatnonzero(t[:lay.n_rbd])  # the few features the candidate loads
            tr = t[nz]
            size = np.sqrt(np.maximum(np.einsum("f,ifg,g->i", tr, rows.raw_G[:, nz[:, None], nz], tr), 0) / n)
            assert raw_rms is not None  # raw_signal and raw_G are recorded together
            return float(np.max(size / np.maximum(raw_rms, 1e-9)))
        best = 0.0
        nz = np.flatnonzero(t)
        tz = t[nz]
        for j in range(lay.robot.n_joints):
            d = n_rbd_dims + j
            if train.n[d] <= 0:
                continue
            g = lay.actuation_feature(j, "gain")
            tau_rms = np.sqrt(train.G[d][g, g] / train.n[d])
            quad = tz @ train.G[d][np.ix_(nz, nz)] @ tz
            best = max(best, float(np.sqrt(max(quad, 0) / train.n[d]) / max(tau_rms, 1e-9)))
        return best

    return relevance


def kind_dimensions(layout: FeatureLayout) -> dict[str, np.ndarray]:
    """Output dimensions each kind of candidate explains (a sensor effect: both Φ̃' and Γ)."""
    n_rbd = 6 + 3 * layout.robot.n_feet
    rbd, act = np.arange(n_rbd), n_rbd + np.arange(layout.robot.n_joints)
    return {"rbd": rbd, "actuation": act, "sensor": np.concatenate([rbd, act])}


class _Problem:
    """Weighted Grams of some output dimensions (all, or one kind's)."""

    def __init__(self, layout, train: Grams, heldout: Grams, w: np.ndarray, dims: np.ndarray):
        wk = np.zeros_like(w)
        wk[dims] = w[dims]
        self.layout = layout
        self.Gt, self.ct, _ = train.weighted(wk)
        self.Gh, self.ch, self.sh = heldout.weighted(wk)
        self.rows = float(heldout.n[dims].sum())
        self.start: dict[str, Any] = {}  # warm starts of the non-linear parameters and the payload's CoM (fit_model)

    def fit(self, cands: list[Candidate]) -> Model:
        m = fit_model(self.layout, cands, self.Gt, self.ct, start=self.start)
        for label, v in m.nonlinear.items():
            self.start.setdefault(label, v)
        payload = _payload(cands)
        if payload is not None and m.payload_com is not None:
            self.start[payload.label] = m.payload_com  # the last fit's: the next set differs by one effect
        return m

    def ss(self, model: Model) -> float:
        return _heldout_ss(model, self.Gh, self.ch, self.sh)


def _grouped(k: Candidate, current: list[Candidate]) -> bool:
    """k nests or is nested by a candidate of the model (one group: e.g. Stribeck and Coulomb friction
    of a joint): the two never enter one model."""
    return k.group is not None and any(c.group == k.group for c in current)


def _select_all(prob: _Problem, cands: list[Candidate], steps: list[Step], total_nominal: float,
                fixed: list[Candidate], thresholds: dict[str, float], progress=None, relevance=None,
                limited: dict | None = None, start: list[Candidate] | None = None) -> list[Candidate]:
    """Forward selection, swaps and backward pruning over every kind (module docstring).

    A candidate is accepted when its held-out gain reaches its kind's threshold. `fixed`
    candidates (the baseline) are part of every fit and never selected or dropped. `limited`
    collects candidates whose estimate ended on a non-null physical bound although they would
    have reduced the held-out residual by their threshold: label → (candidate, model, gain).
    `start`: effects to begin with (a previous selection's, on other rows), each in the simplest form
    of its group (a Stribeck friction as the Coulomb friction it nests: the extra parameters must pass
    the test again); those on a bound or negligible here are left out, then swaps within their groups
    are tried, then the forward steps, and the pruning drops those that do not pay for themselves here."""
    diag = np.diag(prob.Gt)
    usable = [k for k in cands if np.any(diag[list(k.features)] > 0)]
    current: list[Candidate] = []
    for k in start or []:
        simplest = min((c for c in usable if c is k or (k.group is not None and c.group == k.group)),
                       key=lambda c: c.n_params, default=None)
        if simplest is not None and simplest not in current:
            current.append(simplest)
    if current:
        m = prob.fit(fixed + current)
        current = [k for k in current
                   if not _at_bound(m, k) and (relevance is None or relevance(m, k) >= MIN_RELEVANCE)]
    for k in current:
        steps.append(Step(f"{k.label} (from the previous selection)", 0.0, None, 0.0))
    current_ss = prob.ss(prob.fit(fixed + current))

    def thr(k: Candidate) -> float:
        return thresholds[k.kind]

    def trial(cset: list[Candidate], k: Candidate | None, ss_now: float | None = None) -> tuple[float, Model] | None:
        m = prob.fit(fixed + cset)
        if k is not None and _at_bound(m, k):
            if limited is not None and ss_now is not None and _at_far_bound(m, k):
                gain = ss_now - prob.ss(m)
                if gain >= thr(k):
                    limited[k.label] = (k, m, gain)
            return None
        if k is not None and relevance is not None and relevance(m, k) < MIN_RELEVANCE:
            return None
        return prob.ss(m), m

    def swaps(within_groups: bool = False) -> None:
        """Swaps: an effect chosen early (before others were modelled) may be the wrong one.
        within_groups: only for a member of its own group (Coulomb → Stribeck friction of the joint)."""
        nonlocal current_ss
        improved = True
        while improved:
            improved = False
            best: tuple[float, int | None, Candidate | None] = (np.inf, None, None)
            for i in range(len(current)):
                for k2 in usable:
                    if k2 in current or not k2.in_catalogue or _grouped(k2, current[:i] + current[i + 1:]):
                        continue
                    if within_groups and (k2.group is None or k2.group != current[i].group):
                        continue
                    cset = current[:i] + [k2] + current[i + 1:]
                    t = trial(cset, k2)
                    margin = SWAP_MARGIN * min(thr(k2), thr(current[i]))
                    if k2.group is not None and k2.group == current[i].group and k2.n_params > current[i].n_params:
                        margin = thr(k2)  # a nesting effect's extra parameters pass the test of a new effect
                    if t is not None and t[0] < current_ss - margin and t[0] < best[0]:
                        best = (t[0], i, k2)
            _, at, replacement = best
            if at is not None and replacement is not None:
                steps.append(Step(f"{replacement.label} (replaces {current[at].label})",
                                  (current_ss - best[0]) / total_nominal, None, 0.0))
                current[at] = replacement
                current_ss = best[0]
                improved = True

    if current:
        swaps(within_groups=True)  # the others were modelled together already; new ones swap below
    while len(current) < MAX_EFFECTS:
        trials = []
        for k in usable:
            if k in current or _grouped(k, current):
                continue
            t = trial(current + [k], k, current_ss)
            if t is not None and current_ss - t[0] >= thr(k):
                trials.append((current_ss - t[0], k))
        if progress is not None:
            progress()
        if not trials:
            break
        # the out-of-catalogue probes compete with a discounted gain (module docstring); gains are
        # compared relative to each kind's threshold so that a kind with a larger nominal residual
        # does not outbid the others by size alone
        score = {id(k): g * (1.0 if k.in_catalogue else 1.0 - OUT_OF_CATALOGUE_MARGIN) for g, k in trials}
        trials.sort(key=lambda x: -score[id(x[1])])
        best_score = score[id(trials[0][1])]
        near = [t for t in trials if score[id(t[1])] >= (1 - PARSIMONY) * best_score]
        gain, k = min(near, key=lambda t: (t[1].n_params, -score[id(t[1])]))
        runner = next((t for t in trials if t[1] is not k), None)
        steps.append(Step(k.label, gain / total_nominal, runner[1].label if runner else None,
                          runner[0] / total_nominal if runner else 0.0))
        current.append(k)
        current_ss -= gain
        swaps()
    # effects pushed onto a physical bound (or to a negligible size) once the others are modelled
    # do not explain the data
    while current:
        m = prob.fit(fixed + current)
        stuck = [k for k in current if _at_bound(m, k) or (relevance is not None and relevance(m, k) < MIN_RELEVANCE)]
        if not stuck:
            break
        for k in stuck:
            if limited is not None and _at_far_bound(m, k):
                limited[k.label] = (k, m, 0.0)
            current.remove(k)
            steps.append(Step(f"dropped {k.label} (parameter on its physical bound or negligible)", 0.0, None, 0.0))
        current_ss = prob.ss(prob.fit(fixed + current))
    # backward pruning: drop effects that no longer pay for themselves (e.g. an actuator gain once the
    # torque sensor's gain at that joint explains both Φ̃ and Γ)
    while current:
        costs = []
        for k in current:
            m = prob.fit(fixed + [x for x in current if x is not k])
            costs.append(((prob.ss(m) - current_ss) / thr(k), prob.ss(m) - current_ss, k))
        rel, cost, k = min(costs, key=lambda x: x[0])
        if rel >= 1.0:
            break
        current.remove(k)
        current_ss = prob.ss(prob.fit(fixed + current))
        steps.append(Step(f"dropped {k.label}", -cost / total_nominal, None, 0.0))
    return current


def _fall_back_to_nested(prob: _Problem, fixed: list[Candidate], current: list[Candidate], cands: list[Candidate],
                         rejected: Candidate, thresholds: dict[str, float], relevance, steps: list[Step],
                         total_nominal: float) -> None:
    """After `rejected` (a nesting effect, e.g. Stribeck friction) is rejected, put back the best effect
    it nests (Coulomb friction of the joint) if that pays for itself (in place)."""
    nested = [k for k in cands if k.group is not None and k.group == rejected.group and k.n_params < rejected.n_params
              and k not in current]
    ss_now = prob.ss(prob.fit(fixed + current))
    best = None
    for k in nested:
        m = prob.fit(fixed + current + [k])
        gain = ss_now - prob.ss(m)
        ok = not _at_bound(m, k) and (relevance is None or relevance(m, k) >= MIN_RELEVANCE)
        if ok and gain >= thresholds[k.kind] and (best is None or gain > best[0]):
            best = (gain, k)
    if best is not None:
        current.append(best[1])
        steps.append(Step(f"{best[1].label} (in place of the rejected {rejected.label})", best[0] / total_nominal,
                          None, 0.0))


def _prune(prob: _Problem, fixed: list[Candidate], current: list[Candidate], thresholds: dict[str, float],
           relevance, steps: list[Step], total_nominal: float) -> None:
    """Drop (in place) effects that became negligible or no longer pay for themselves once others were
    rejected or dropped (e.g. a stand-in that took part of a rejected effect's data, now near zero)."""
    while current:
        m = prob.fit(fixed + current)
        ss_now = prob.ss(m)
        worst = None
        for k in current:
            if relevance is not None and relevance(m, k) < MIN_RELEVANCE:
                worst = (k, -np.inf, 0.0)
                break
            cost = prob.ss(prob.fit(fixed + [x for x in current if x is not k])) - ss_now
            if cost < thresholds[k.kind] and (worst is None or cost / thresholds[k.kind] < worst[1]):
                worst = (k, cost / thresholds[k.kind], cost)
        if worst is None:
            return
        current.remove(worst[0])
        steps.append(Step(f"dropped {worst[0].label} (no longer pays for itself after the rejections)",
                          -worst[2] / total_nominal, None, 0.0))


def consistency(model: Model, subsets: list[Grams], weights: np.ndarray, extra=None) -> list[float]:
    """Relative spread of each effect's main parameter over data subsets (contact configurations,
    bags): refit that effect alone on each subset, the others held at their estimates, and take
    the information-weighted RMS deviation from the overall estimate, divided by its size. The
    information is the main parameter's own (the Schur complement of the others in the subset's
    normal matrix): a subset that fixes an effect's other parameters but not its main one (a
    Stribeck friction's fast-sliding bin, which sees only its Coulomb level) weighs nothing.
    A physical effect has one value everywhere; a stand-in for an effect outside the catalogue
    (a term that fits on average but not condition by condition) has not. extra(candidate) → more
    subsets for that candidate (e.g. a joint friction's sliding-speed bins: a friction whose level
    changes with speed, like Stribeck friction, is not Coulomb friction)."""
    theta = model.feature_theta()
    A = model.matrix()
    out = []
    for i, sl in enumerate(model.slices()):
        Ak, tk = A[:, sl], model.theta[sl]
        est_list: list[float] = []
        info_list: list[float] = []
        cand = model.candidates[i]
        if not cand.in_catalogue:
            out.append(0.0)
            continue
        for g in list(subsets) + (list(extra(cand)) if extra is not None else []):
            G, c, _ = g.weighted(weights)
            H = Ak.T @ G @ Ak
            info = _main_information(H)
            if info <= 0:
                continue
            d = np.linalg.lstsq(H, Ak.T @ (c - G @ theta), rcond=None)[0]
            est_list.append(float((tk + d)[0]))
            info_list.append(info)
        if not info_list:
            out.append(0.0)
            continue
        ests, infos = np.array(est_list), np.array(info_list)
        ok = infos >= MIN_SUBSET_INFORMATION * infos.sum()
        dev = np.sqrt(np.sum(infos[ok] * (ests[ok] - tk[0]) ** 2) / infos[ok].sum())
        out.append(float(dev / max(abs(tk[0]), 1e-12)))
    return out


def _main_information(H: np.ndarray) -> float:
    """Information on the first parameter with the others free: H₀₀ − H₀ᵣ H_rr⁺ H_r0."""
    h = float(H[0, 0])
    if len(H) > 1:
        h -= float(H[0, 1:] @ np.linalg.lstsq(H[1:, 1:], H[1:, 0], rcond=None)[0])
    return max(h, 0.0)


def noise_floor(layout: FeatureLayout, heldout: Grams, sigma: np.ndarray) -> np.ndarray:
    """Per output dimension [N or Nm], the held-out error no model could remove: the RMS residual of
    an in-sample fit of every catalogue feature *on the held-out data itself*, capped at the median of
    its pool of dimensions of the same kind (an effect outside the catalogue at one joint or leg
    raises that dimension's residual, not its pool's median: it stays above the floor, unexplained).
    Dimensions without held-out rows get σ_d."""
    _, rms = noise_levels(layout, heldout)
    floor = np.asarray(sigma, float).copy()
    for pool in dimension_pools(layout):
        obs = pool[heldout.n[pool] > 0]
        if len(obs) == 0:
            continue
        med = float(np.median(rms[obs]))
        floor[obs] = np.minimum(rms[obs], med)
    return floor


def select(layout: FeatureLayout, train: Grams, heldout: Grams, progress=None,
           candidates: list[Candidate] | None = None, subsets: list[Grams] | None = None,
           relevance=None, candidate_subsets=None, start: list[Candidate] | None = None,
           report_sigma: np.ndarray | None = None) -> Selection:
    """Greedy forward selection with swaps and backward pruning (module docstring).

    Every kind of candidate competes in one loop on all output dimensions (rigid-body and actuation
    candidates explain disjoint rows, a torque-sensor effect both); each is accepted against the
    threshold of its kind, relative to that kind's own nominal residual. The baseline
    (command-update sampling, candidates.py) is part of every model: the "nominal" residual is
    the one after it. With `subsets` (Grams of parts of the identification data), effects whose
    parameter is not consistent across them (consistency() > MAX_SPREAD) are rejected. `start`: effects
    of a previous selection to begin with (_select_all); `report_sigma`: its noise levels, in which the
    gap, the shares and `Selection.sigma` are then given (the fits use this data's own; `fit_weights`)."""
    cands = list(layout.candidates if candidates is None else candidates)
    base = [layout.baseline]
    sigma, full_rms = noise_levels(layout, train, heldout)
    w = 1.0 / sigma ** 2
    Gt, ct, _ = train.weighted(w)
    Gh, ch, sh = heldout.weighted(w)
    nominal = _heldout_ss(fit_model(layout, base, Gt, ct), Gh, ch, sh)
    thresholds = {}
    for kind, dims in kind_dimensions(layout).items():
        pk = _Problem(layout, train, heldout, w, dims)
        nom_k = pk.ss(pk.fit(base))
        thresholds[kind] = max(MIN_SHARE * nom_k, MIN_NOISE_GAIN * pk.rows)
    steps: list[Step] = []
    limited: dict = {}
    prob = _Problem(layout, train, heldout, w, np.arange(len(sigma)))
    current = _select_all(prob, cands, steps, nominal, base, thresholds, progress, relevance, limited, start)
    model = fit_model(layout, base + current, Gt, ct)
    rejected: list[tuple[str, float]] = []
    if (subsets or candidate_subsets) and current:
        spread = consistency(model, subsets or [], w, candidate_subsets)[len(base):]
        for k, sp in [(k, sp) for k, sp in zip(current, spread) if sp > MAX_SPREAD]:
            current.remove(k)
            rejected.append((k.label, sp))
            steps.append(Step(f"rejected {k.label}: its parameter varies by {sp:.0%} across contact "
                              "configurations and bags", 0.0, None, 0.0))
            _fall_back_to_nested(prob, base, current, cands, k, thresholds, relevance, steps, nominal)
        model = fit_model(layout, base + current, Gt, ct)
    # after every refit: an estimate on a physical bound is not identified (bounds.py)
    stuck = [k for k in current if _at_bound(model, k)]
    for k in stuck:
        if _at_far_bound(model, k):
            limited[k.label] = (k, model, 0.0)
        current.remove(k)
        steps.append(Step(f"dropped {k.label} (parameter on its physical bound after the final refit)", 0.0, None, 0.0))
    model = fit_model(layout, base + current, Gt, ct)
    if rejected or stuck:
        _prune(prob, base, current, thresholds, relevance, steps, nominal)
        model = fit_model(layout, base + current, Gt, ct)
    current_ss = _heldout_ss(model, Gh, ch, sh)
    # the reported gap and shares: models fitted with this data's weights, measured in the report's
    rs = sigma if report_sigma is None else np.asarray(report_sigma, float)
    Gr, cr, sr = (Gh, ch, sh) if report_sigma is None else heldout.weighted(1.0 / rs ** 2)
    nominal_r = nominal if report_sigma is None else _heldout_ss(fit_model(layout, base, Gt, ct), Gr, cr, sr)
    current_r = _heldout_ss(model, Gr, cr, sr)
    floor = noise_floor(layout, heldout, rs)
    floor_ss = float(np.sum(heldout.n * (floor / rs) ** 2))
    gap = max(nominal_r - floor_ss, 0.0)
    # shares: the explained part of the gap above the noise floor, split by the drop-one cost of each effect
    explained = (max(0.0, min(1.0, (nominal_r - current_r) / gap)) if gap > GAP_AT_FLOOR * nominal_r else 0.0)
    drop = []
    for k in current:
        m = fit_model(layout, base + [x for x in current if x is not k], Gt, ct)
        drop.append(max(0.0, _heldout_ss(m, Gr, cr, sr) - current_r))
    total = sum(drop)
    shares = [explained * d / total if total > 0 else explained / len(current) for d in drop] if current else []
    order = list(np.argsort(shares)[::-1])
    model = fit_model(layout, base + [current[i] for i in order], Gt, ct)
    spread = (consistency(model, subsets or [], w, candidate_subsets)[len(base):]
              if (subsets or candidate_subsets) else [0.0] * len(order))
    # a candidate pushed onto a bound is reported only if it still is, and would still explain a part of
    # the data, next to the final effects (not a stand-in tried before the right effect entered)
    not_identified = []
    for label, (k, _, _) in sorted(limited.items()):
        if k in current or not k.in_catalogue:
            continue
        m = fit_model(layout, base + current + [k], Gt, ct)
        gain = current_ss - _heldout_ss(m, Gh, ch, sh)
        if _at_far_bound(m, k) and gain >= thresholds[k.kind]:
            not_identified.append(_not_identified_entry(k, m, gain / nominal if nominal > 0 else 0.0))
    return Selection(model=model, sigma=rs, weights=1.0 / rs ** 2, nominal_ss=nominal_r, final_ss=current_r,
                     shares=[shares[i] for i in order], steps=steps, full_fit_rms=full_rms,
                     spread=spread, rejected=rejected, raw_nominal_ss=float(sr), n_baseline=len(base),
                     floor_ss=floor_ss, noise_floor=floor, not_identified=not_identified, fit_weights=w)


def _not_identified_entry(cand: Candidate, model: Model, gain_share: float) -> dict:
    """An effect whose estimate ends on a physical bound (bounds.py): reported with its bound, no confidence."""
    th = model.params_of(cand)
    lo, hi = np.asarray(cand.lower), np.asarray(cand.upper)
    names = [n for n, t, a, b in zip(cand.param_names, th, lo, hi) if _on(t, a) or _on(t, b)]
    if _nonlinear_at_bound(model, cand):
        names.append(_nonlinear_range(cand)[0])  # type: ignore[index]
    e: dict[str, Any] = {"type": cand.type}
    e.update(cand.location())
    e.update({"params": _physical_of(model, cand), "status": "at bound — not identified", "confidence": None,
              "parameters_at_bound": names, "heldout_gain_share": float(gain_share),
              "description": "the data push this parameter to the edge of its physical range (bounds.py); "
                             "the effect does not explain them as a physical effect would"})
    return e


def _on(t: float, b: float, rel: float = 1e-6) -> bool:
    return bool(np.isfinite(b) and abs(t - b) <= rel * max(abs(t), 1.0) + 1e-12)


# --- physical parameters ---------------------------------------------------------------------

@dataclass(frozen=True)
class CommandSampling:
    """How the logs sample their command: what a first-order lag's coefficient reads (lag_reading).

    From loginputs' stamp_report["command_sampling"] of each log, pooled over the identification
    logs (pooled_command_sampling)."""

    period: float          # [s] Δ, the command period (median step of the command stamps)
    phase: np.ndarray      # the samples' phases φ/Δ ∈ (0, 1]: time since the stamp of the command paired with them
    weight: np.ndarray     # the share of the samples at each phase (sums to 1)
    staircase_share: dict[str, float]  # f per joint and "all": the share of the command's rate made at its updates
    sample_period: float   # [s] the logs' sample period: the resolution of a torque reading's timing

    def share(self, joint: str | None) -> float:
        return self.staircase_share.get(joint or "all", self.staircase_share.get("all", 1.0))


def staircase_reading(T: float, period: float, phase: np.ndarray, weight: np.ndarray) -> float:
    """The coefficient c that Γ = τ − u = −c τ̇ reads for a first-order lag T of a staircase command
    (each command held for `period` Δ) in samples at the given phases φ/Δ of the period.

    A sample at phase φ is paired with the command in force, u_k (pairing.py); the torque has
    followed that step for φ only. On a command ramp u_k = s(t_k), ṡ = b, the lag's steady state
    is u_k − τ(t_k) = bΔ / (1 − e^{−Δ/T}), so τ − u_k = −b Δ e^{−φ/T} / (1 − e^{−Δ/T}) while τ
    rises at b: c(φ) = Δ e^{−φ/T} / (1 − e^{−Δ/T}). Averaged over uniform phases c = T exactly;
    on the command instants (φ = Δ, the command before them) c = Δβ/(1 − β) ≈ T − Δ/2
    (β = e^{−Δ/T}: 7.7 ms for 10 ms at 250 Hz); without lag (T → 0) c = 0 at every phase."""
    if T <= 0:
        return 0.0
    r = period / T
    return float(np.sum(weight * period * np.exp(-np.asarray(phase) * r)) / -np.expm1(-r))


def lag_reading(T: float, sampling: CommandSampling, joint: str | None = None) -> float:
    """c of a lag T when a share f of the command's rate is a staircase (staircase_reading) and the
    rest continuous in time (the joint loop's feedback on the measured state: c = T at any phase)."""
    f = sampling.share(joint)
    return (1.0 - f) * T + f * staircase_reading(T, sampling.period, sampling.phase, sampling.weight)


def lag_time_constant(c: float, sampling: CommandSampling | None,
                      joint: str | None = None) -> tuple[float, float]:
    """(T, its conversion standard deviation) of a fitted lag coefficient c: lag_reading inverted
    (it grows with T from 0). The conversion std is the timing of the torque readings: a torque
    sample stands for an instant somewhere in its sample period (a drive averaging over it, a
    joint loop reporting the torque it applies next), and a timing offset δ reads as a lag
    shifted by δ; uniform over ±½ sample period, std = sample period / √12. Without sampling
    information (no command period measured): (c, 0)."""
    if sampling is None or not sampling.period > 0:
        return float(c), 0.0
    c = float(c)
    if c <= 0:
        return 0.0, 0.0
    hi = c + sampling.period
    while lag_reading(hi, sampling, joint) < c:  # reading ≥ T − Δ: found within a few doublings
        hi *= 2.0
    T = float(brentq(lambda x: lag_reading(x, sampling, joint) - c, 0.0, hi, xtol=1e-12, rtol=1e-12))
    return T, sampling.sample_period / np.sqrt(12.0)


def pooled_command_sampling(reports: list[dict], sample_period: float) -> CommandSampling | None:
    """One CommandSampling from the logs' stamp_report["command_sampling"] entries (loginputs), each
    weighted by its sample count; None when no log has one (no command)."""
    reports = [r for r in reports if r and r.get("samples")]
    if not reports:
        return None
    n = np.array([r["samples"] for r in reports], float)
    phase = np.concatenate([[p for p, _ in r["phases"]] for r in reports])
    weight = np.concatenate([np.array([w for _, w in r["phases"]]) * k for r, k in zip(reports, n)])
    keys = set().union(*(r["staircase_share"] for r in reports))
    share = {k: float(np.average([r["staircase_share"].get(k, r["staircase_share"]["all"]) for r in reports],
                                 weights=n)) for k in keys}
    return CommandSampling(period=float(np.average([r["period_s"] for r in reports], weights=n)),
                           phase=phase, weight=weight / weight.sum(), staircase_share=share,
                           sample_period=float(sample_period))


def physical_parameters(model: Model) -> list[dict]:
    """Each candidate's parameters in the scenario's terms (docs/ARCHITECTURE.md §5), e.g. {"value": 5.8}.

    Actuation parameters of one joint are converted together: with a = 1 − 1/g, b = o/g,
    c = T/g (candidates.py), g = 1/(1 − a), o = b g, T = c g (c first corrected for
    for how the logs sample the command, lag_time_constant). Torque-sensor effects:
    g_s = 1/(1 − a_s), o_s = b_s g_s.
    """
    conv = Conversion(lag_time_constant=lambda c, joint: lag_time_constant(c, model.sampling, joint)[0],
                      nonlinear=dict(model.nonlinear))
    for cand in model.candidates:
        if cand.type in ("torque_gain", "torque_sensor_gain"):
            gains = conv.gain if cand.type == "torque_gain" else conv.sensor_gain
            gains[str(cand.joint)] = 1.0 / (1.0 - float(model.params_of(cand)[0]))
    out = []
    for cand in model.candidates:
        th = model.params_of(cand)
        p: dict[str, Any]
        if cand.type == "command_update_sampling":
            p = {"qd": float(th[0]), "qdd": float(th[1]), "udot": float(th[2])}
        elif not cand.in_catalogue:
            p = {"coefficients": [float(x) for x in th]}
        else:
            p = effect_type(cand.type).to_physical(th, cand, conv)
        out.append(p)
    return out


def _flatten(params: list[dict]) -> np.ndarray:
    vals = []
    for p in params:
        for v in p.values():
            vals.extend(np.atleast_1d(v).tolist())
    return np.asarray(vals, float)


def _unflatten(like: list[dict], flat: np.ndarray) -> list[dict]:
    out, k = [], 0
    for p in like:
        q = {}
        for key, v in p.items():
            n = len(np.atleast_1d(v))
            q[key] = flat[k:k + n].tolist() if isinstance(v, list) else float(flat[k])
            k += n
        out.append(q)
    return out


def _block_grams(selection: Selection, rows: Rows, feats: np.ndarray, block: int) -> tuple[np.ndarray, np.ndarray]:
    """Per time block of the identification rows: weighted Gram matrices over the features `feats`."""
    layout = selection.model.layout
    n_s = len(rows.samples)
    n_blocks = max(1, int(np.ceil(n_s / block)))
    Gb = np.zeros((n_blocks, len(feats), len(feats)))
    cb = np.zeros((n_blocks, len(feats)))
    n_rbd_dims = 6 + 3 * layout.robot.n_feet
    w = selection.fitted_with
    rbd_feats = feats[feats < layout.n_rbd]
    pos_r = np.searchsorted(feats, rbd_feats)
    if len(rbd_feats):
        X = rows.X_rbd[:, rbd_feats].astype(float)
        wr = w[rows.dim_rbd]
        b_of = rows.sample_rbd // block
        for b in range(n_blocks):
            m = b_of == b
            Xm = X[m] * np.sqrt(wr[m])[:, None]
            Gb[b][np.ix_(pos_r, pos_r)] += Xm.T @ Xm
            cb[b, pos_r] += (X[m] * wr[m][:, None]).T @ rows.y_rbd[m]
    for j in range(layout.robot.n_joints):
        fj = layout.actuation_block(j)
        sel = np.isin(fj, feats)
        if not sel.any():
            continue
        pos = np.searchsorted(feats, fj[sel])
        Xj = rows.X_act[:, j, sel]
        yj = rows.y_act[:, j]
        wj = w[n_rbd_dims + j]
        for b in range(n_blocks):
            sl = slice(b * block, min(n_s, (b + 1) * block))
            Gb[b][np.ix_(pos, pos)] += wj * Xj[sl].T @ Xj[sl]
            cb[b, pos] += wj * Xj[sl].T @ yj[sl]
    return Gb, cb


def _residual_series(selection: Selection, rows: Rows) -> list[np.ndarray]:
    """The identification residual after the selected model, one time series per output dimension."""
    from ciml_learning.diagnosis.features import predict

    pr, pa = predict(rows, selection.model.feature_theta())
    out = [(rows.y_rbd - pr)[rows.dim_rbd == d] for d in np.unique(rows.dim_rbd)]
    out += [(rows.y_act - pa)[:, j] for j in range(rows.y_act.shape[1])]
    return [r for r in out if len(r) >= 4 and np.any(r)]


def parameter_uncertainty(selection: Selection, rows: Rows, heldout: Grams | None = None, fs: float = 250.0,
                          n_boot: int = BOOTSTRAP, seed: int = 0) -> tuple[list[dict], dict]:
    """Standard deviation of each candidate's physical parameters (uncertainty.py: block bootstrap
    with blocks from the residual's autocorrelation, held-out reproduction, the lag's conversion),
    and a summary of how it was obtained (block length; `components`: per candidate, the standard
    deviation of each component before they are combined)."""
    from ciml_learning.diagnosis import uncertainty as unc

    model = selection.model
    if not model.candidates:
        return [], {}
    layout = model.layout
    feats = np.unique(np.concatenate([np.asarray(c.features) for c in model.candidates]))
    n_s = len(rows.samples)
    block = unc.block_length(_residual_series(selection, rows), fs, n_s)
    Gb, cb = _block_grams(selection, rows, feats, block)
    nf = layout.n_features
    base = physical_parameters(model)

    def fit(Gs: np.ndarray, cs: np.ndarray) -> np.ndarray:
        G = np.zeros((nf, nf))
        c = np.zeros(nf)
        G[np.ix_(feats, feats)] = Gs
        c[feats] = cs
        return _flatten(physical_parameters(fit_model(layout, model.candidates, G, c, sampling=model.sampling,
                                                      start=model.warm_start())))

    draws = unc.block_bootstrap(Gb, cb, fit, n_boot, seed)
    sampling = unc.bootstrap_std(draws, len(Gb))
    flat = _flatten(base)
    reproduction = np.zeros_like(flat)
    if heldout is not None and np.any(heldout.n > 0):
        Gh, ch, _ = heldout.weighted(selection.fitted_with)
        m_ho = fit_model(layout, model.candidates, Gh, ch, sampling=model.sampling, start=model.warm_start())
        reproduction = np.abs(_flatten(physical_parameters(m_ho)) - flat) / np.sqrt(2.0)
    conversion = np.zeros_like(flat)
    misspecification = np.zeros_like(flat)
    resolution = np.zeros_like(flat)
    rel_mis = misspecification_bounds(selection, heldout) if heldout is not None else [0.0] * len(base)
    k = 0
    for cand, p, rel in zip(model.candidates, base, rel_mis):
        n = len(_flatten([p]))
        if cand.type == "actuator_lag" and model.sampling is not None:
            T, conv = lag_time_constant(float(model.params_of(cand)[0]), model.sampling, cand.joint)
            conversion[k] = conv * (p["time_constant"] / T if T > 0 else 1.0)  # × the joint's gain
        # deviations from the null value ("no effect") scale with the bound
        null = _flatten([{key: _null_of(cand, key, v) for key, v in p.items()}])
        misspecification[k:k + n] = unc.MISSPECIFICATION_SCALE * rel * np.abs(flat[k:k + n] - null)
        resolution[k:k + n] = unc.RESOLUTION * np.abs(flat[k:k + n] - null)
        k += n
    parts = {"sampling": sampling, "reproduction": reproduction, "conversion": conversion,
             "misspecification": misspecification, "resolution": resolution}
    std = unc.combine(*parts.values())
    info = {"method": "block bootstrap over time (blocks from the residual's autocorrelation), held-out "
                      "reproduction, the lag's conversion (timing of the torque readings), in quadrature",
            "block_seconds": block * unc.SPAN / fs, "block_starts_every_s": block / fs,
            "autocorrelation_time_s": unc.integrated_autocorrelation_time_max(_residual_series(selection, rows)) / fs,
            "draws": int(len(draws)),
            # per candidate, each component's standard deviation (the bench's calibration reads them)
            "components": [dict(zip(parts, per)) for per in zip(*(_unflatten(base, v) for v in parts.values()))]}
    return _unflatten(base, std), info


def _null_of(cand: Candidate, key: str, value: Any) -> Any:
    """A physical parameter's "no effect" value (the effect type's null; 0 for the baseline and probes)."""
    t = EFFECTS.get(cand.type) if cand.in_catalogue else None
    null = t.null.get(key, 0.0) if t is not None else 0.0
    return [0.0] * len(value) if isinstance(value, list) and not isinstance(null, list) else null


def misspecification_bounds(selection: Selection, heldout: Grams) -> list[float]:
    """Per candidate of the selected model, the relative bias a residual the model leaves could cause
    (uncertainty.py, misspecification): √(r² / s²) with s² the candidate's own held-out prediction
    (normalised SS) and r² the held-out residual above the noise floor in the dimensions it acts on
    (those holding ≥ 1 % of its prediction). Cauchy–Schwarz: a least-squares coefficient moves by at most
    that fraction when such a residual is added to its data."""
    model = selection.model
    if not model.candidates:
        return []
    w = selection.fitted_with
    theta = model.feature_theta()
    res = heldout.ss(theta)  # per dimension, physical units²
    floor = (heldout.n * (selection.noise_floor ** 2) if selection.noise_floor is not None
             else np.zeros_like(res))
    above = np.maximum(res - floor, 0.0) * w
    A = model.matrix()
    out = []
    for sl in model.slices():
        t = A[:, sl] @ model.theta[sl]
        own = np.einsum("i,dij,j->d", t, heldout.G, t) * w
        total = own.sum()
        if total <= 0:
            out.append(0.0)
            continue
        dims = own >= 0.01 * own.max()
        out.append(float(np.sqrt(above[dims].sum() / total)))
    return out


def bootstrap_std(selection: Selection, rows: Rows, fs: float = 250.0, n_boot: int = BOOTSTRAP,
                  seed: int = 0) -> list[dict]:
    """Standard deviations only (parameter_uncertainty without held-out data)."""
    return parameter_uncertainty(selection, rows, None, fs, n_boot, seed)[0]
