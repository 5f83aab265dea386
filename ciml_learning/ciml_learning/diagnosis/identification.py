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

Selection. Rigid-body and actuation candidates explain disjoint rows, so each kind is selected
on its own. Starting from the baseline, each step refits every current candidate plus one new
candidate on the identification data (bounds: friction, viscosity, lag, mass ≥ 0, mass scale
> 0, gain > 0; proxsuite QP) and measures the normalised residual on held-out data. The
candidate with the largest held-out reduction is accepted if that reduction is at least
MIN_SHARE of the kind's nominal held-out residual (and MIN_NOISE_GAIN of its noise power), its
parameters are not on a physical bound, and it is not negligible (relevance_function: at least
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

Shares. unexplained_share = held-out residual / nominal held-out residual (normalised sums of
squares); the explained part 1 − unexplained_share is split among the effects in proportion
to what removing each one costs on held-out data.

Uncertainty. Parameter standard deviations from a moving-block bootstrap over time (blocks of
BLOCK_SECONDS), which respects the strong autocorrelation of low-passed signals.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .candidates import Candidate, FeatureLayout
from .features import Grams, Rows

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
BLOCK_SECONDS = 1.0
BOOTSTRAP = 100
MAX_EFFECTS = 12
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

    def matrix(self) -> np.ndarray:
        if not self.candidates:
            return np.zeros((self.layout.n_features, 0))
        return np.hstack([self.layout.matrix(c, self.payload_com, self.lag_scale) for c in self.candidates])

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
                     self.lag_scale)

    def params_of(self, cand: Candidate) -> np.ndarray:
        i = self.candidates.index(cand)
        return self.theta[self.slices()[i]]


def _bounds(cands: list[Candidate]) -> tuple[np.ndarray, np.ndarray]:
    lo = np.concatenate([np.asarray(c.lower, float) for c in cands]) if cands else np.zeros(0)
    hi = np.concatenate([np.asarray(c.upper, float) for c in cands]) if cands else np.zeros(0)
    return lo, hi


def fit_model(layout: FeatureLayout, cands: list[Candidate], G: np.ndarray, c: np.ndarray,
              refine_payload: int = 3) -> Model:
    """Fit the parameters of a candidate set on weighted Grams (G = Σ w_d G_d, c = Σ w_d c_d).

    Two terms are bilinear and refined by refitting (refine iterations): a payload's point-mass
    rotational inertia depends on its CoM; the all-joint lag's coefficient on a joint with an
    identified torque gain is T/g_j."""
    model = Model(layout, list(cands), np.zeros(sum(k.n_params for k in cands)))
    if not cands:
        return model
    lo, hi = _bounds(model.candidates)
    payload = next((k for k in cands if k.type == "payload"), None)
    gains = [k for k in cands if k.type == "torque_gain"]
    coupled = bool(gains) and any(k.type == "actuator_lag" and len(k.joints) > 1 for k in cands)
    refine = refine_payload if (payload is not None or coupled) else 0
    for _ in range(1 + refine):
        A = model.matrix()
        model.theta = bounded_least_squares(A.T @ G @ A, A.T @ c, lo, hi)
        if coupled:
            model.lag_scale = {k.joint: float(1.0 - model.params_of(k)[0]) for k in gains}
        if payload is not None:
            p = model.params_of(payload)
            if p[0] < MIN_PAYLOAD_MASS:
                model.payload_com = None
            else:
                com = p[1:4] / p[0]
                n = np.linalg.norm(com)
                model.payload_com = com if n <= MAX_PAYLOAD_LEVER else com * (MAX_PAYLOAD_LEVER / n)
    return model


def _at_bound(model: Model, cand: Candidate, rel: float = 1e-6) -> bool:
    """A parameter on a physical bound: the data push the effect beyond what it can be (friction
    below zero, a mass scale to zero, an offset beyond its range) — it does not explain them."""
    th = model.params_of(cand)
    lo, hi = np.asarray(cand.lower), np.asarray(cand.upper)
    tol = rel * np.maximum(np.abs(th), 1.0) + 1e-12
    on = (np.abs(th - lo) <= tol) | (np.abs(th - hi) <= tol)
    if cand.type == "payload":
        return bool(on[0] or th[0] < MIN_PAYLOAD_MASS or (
            model.payload_com is not None and np.linalg.norm(model.payload_com) >= MAX_PAYLOAD_LEVER * (1 - 1e-9)))
    return bool(on.any())


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
    # the catalogue only: σ is what no catalogue effect explains
    used = np.unique(np.concatenate([np.asarray(c.features) for c in layout.candidates + [layout.baseline]
                                     if c.in_catalogue]))
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
    shares: list[float]          # per selected candidate
    steps: list[Step] = field(default_factory=list)
    full_fit_rms: np.ndarray | None = None
    spread: list[float] = field(default_factory=list)           # consistency() of each selected effect
    raw_nominal_ss: float = 0.0                                  # held-out normalised SS without the baseline
    n_baseline: int = 0                                          # model.candidates[:n_baseline] = the baseline
    rejected: list[tuple[str, float]] = field(default_factory=list)  # (label, spread) rejected as inconsistent

    @property
    def effects(self) -> list[Candidate]:
        return self.model.candidates[self.n_baseline:]

    @property
    def unexplained_share(self) -> float:
        return float(self.final_ss / self.nominal_ss) if self.nominal_ss > 0 else 0.0


def _heldout_ss(model: Model, Gh: np.ndarray, ch: np.ndarray, sh: float) -> float:
    t = model.feature_theta()
    return float(sh - 2 * ch @ t + t @ Gh @ t)


def relevance_function(rows: Rows, train: Grams):
    """relevance(model, cand) → the effect's size relative to the robot's own forces: the largest,
    over generalized coordinates, RMS of its generalized force (before eq. 11; Γ for actuation
    effects) divided by the RMS of the signal there (M q̈ + h on the base, τ on the joints)."""
    lay = rows.layout
    n_rbd_dims = 6 + 3 * lay.robot.n_feet
    n = max(rows.n_raw, 1)
    raw_rms = np.sqrt(np.maximum(rows.raw_signal, 0) / n) if rows.raw_signal is not None else None

    def relevance(model: Model, cand: Candidate) -> float:
        t = model.matrix()[:, model.slices()[model.candidates.index(cand)]] @ model.params_of(cand)
        if cand.kind == "rbd":
            if rows.raw_G is None:
                return np.inf
            tr = t[:lay.n_rbd]
            size = np.sqrt(np.maximum(np.einsum("f,ifg,g->i", tr, rows.raw_G, tr), 0) / n)
            return float(np.max(size / np.maximum(raw_rms, 1e-9)))
        best = 0.0
        for j in range(lay.robot.n_joints):
            d = n_rbd_dims + j
            if train.n[d] <= 0:
                continue
            g = lay.actuation_feature(j, "gain")
            tau_rms = np.sqrt(train.G[d][g, g] / train.n[d])
            best = max(best, float(np.sqrt(max(t @ train.G[d] @ t, 0) / train.n[d]) / max(tau_rms, 1e-9)))
        return best

    return relevance


def kind_dimensions(layout: FeatureLayout) -> dict[str, np.ndarray]:
    n_rbd = 6 + 3 * layout.robot.n_feet
    return {"rbd": np.arange(n_rbd), "actuation": n_rbd + np.arange(layout.robot.n_joints)}


class _Problem:
    """Weighted Grams of one kind of output (rbd or actuation): its candidates touch only its rows."""

    def __init__(self, layout, train: Grams, heldout: Grams, w: np.ndarray, dims: np.ndarray):
        wk = np.zeros_like(w)
        wk[dims] = w[dims]
        self.layout = layout
        self.Gt, self.ct, _ = train.weighted(wk)
        self.Gh, self.ch, self.sh = heldout.weighted(wk)
        self.rows = float(heldout.n[dims].sum())

    def fit(self, cands: list[Candidate]) -> Model:
        return fit_model(self.layout, cands, self.Gt, self.ct)

    def ss(self, model: Model) -> float:
        return _heldout_ss(model, self.Gh, self.ch, self.sh)


def _select_kind(prob: _Problem, cands: list[Candidate], steps: list[Step], total_nominal: float,
                 fixed: list[Candidate], progress=None, relevance=None) -> list[Candidate]:
    """Forward selection, swaps and backward pruning within one kind (module docstring).

    `fixed` candidates (the baseline) are part of every fit and never selected or dropped."""
    nominal = prob.ss(prob.fit(fixed))
    threshold = max(MIN_SHARE * nominal, MIN_NOISE_GAIN * prob.rows)
    current: list[Candidate] = []
    current_ss = nominal
    diag = np.diag(prob.Gt)
    usable = [k for k in cands if np.any(diag[list(k.features)] > 0)]

    def trial(cset: list[Candidate], k: Candidate | None) -> tuple[float, Model] | None:
        m = prob.fit(fixed + cset)
        if k is not None and (_at_bound(m, k) or (relevance is not None and relevance(m, k) < MIN_RELEVANCE)):
            return None
        return prob.ss(m), m

    while len(current) < MAX_EFFECTS:
        trials = []
        for k in usable:
            if k in current:
                continue
            t = trial(current + [k], k)
            if t is not None:
                trials.append((current_ss - t[0], k))
        if progress is not None:
            progress()
        if not trials:
            break
        # the out-of-catalogue probe competes with a discounted gain (module docstring)
        score = {id(k): g * (1.0 if k.in_catalogue else 1.0 - OUT_OF_CATALOGUE_MARGIN) for g, k in trials}
        trials.sort(key=lambda x: -score[id(x[1])])
        best_score = score[id(trials[0][1])]
        if trials[0][0] < threshold:
            break
        near = [t for t in trials if score[id(t[1])] >= (1 - PARSIMONY) * best_score]
        gain, k = min(near, key=lambda t: (t[1].n_params, -score[id(t[1])]))
        runner = next((t for t in trials if t[1] is not k), None)
        steps.append(Step(k.label, gain / total_nominal, runner[1].label if runner else None,
                          runner[0] / total_nominal if runner else 0.0))
        current.append(k)
        current_ss -= gain
        # swaps: an effect chosen early (before others were modelled) may be the wrong one
        improved = True
        while improved:
            improved = False
            best = (current_ss - SWAP_MARGIN * threshold, None, None)
            for i in range(len(current)):
                for k2 in usable:
                    if k2 in current or not k2.in_catalogue:
                        continue
                    cset = current[:i] + [k2] + current[i + 1:]
                    t = trial(cset, k2)
                    if t is not None and t[0] < best[0]:
                        best = (t[0], i, k2)
            if best[1] is not None:
                steps.append(Step(f"{best[2].label} (replaces {current[best[1]].label})",
                                  (current_ss - best[0]) / total_nominal, None, 0.0))
                current[best[1]] = best[2]
                current_ss = best[0]
                improved = True
    # effects pushed onto a physical bound (or to a negligible size) once the others are modelled
    # do not explain the data
    while current:
        m = prob.fit(fixed + current)
        stuck = [k for k in current if _at_bound(m, k) or (relevance is not None and relevance(m, k) < MIN_RELEVANCE)]
        if not stuck:
            break
        for k in stuck:
            current.remove(k)
            steps.append(Step(f"dropped {k.label} (parameter on its physical bound or negligible)", 0.0, None, 0.0))
        current_ss = prob.ss(prob.fit(fixed + current))
    # backward pruning: drop effects that no longer pay for themselves
    while current:
        costs = []
        for k in current:
            m = prob.fit(fixed + [x for x in current if x is not k])
            costs.append((prob.ss(m) - current_ss, k))
        cost, k = min(costs, key=lambda x: x[0])
        if cost >= threshold:
            break
        current.remove(k)
        current_ss = prob.ss(prob.fit(fixed + current))
        steps.append(Step(f"dropped {k.label}", -cost / total_nominal, None, 0.0))
    return current


def consistency(model: Model, subsets: list[Grams], weights: np.ndarray, extra=None) -> list[float]:
    """Relative spread of each effect's main parameter over data subsets (contact configurations,
    bags): refit that effect alone on each subset, the others held at their estimates, and take
    the information-weighted RMS deviation from the overall estimate, divided by its size.
    A physical effect has one value everywhere; a stand-in for an effect outside the catalogue
    (a term that fits on average but not condition by condition) has not. extra(candidate) → more
    subsets for that candidate (e.g. a joint friction's sliding-speed bins: a friction whose level
    changes with speed, like Stribeck friction, is not Coulomb friction)."""
    theta = model.feature_theta()
    A = model.matrix()
    out = []
    for i, sl in enumerate(model.slices()):
        Ak, tk = A[:, sl], model.theta[sl]
        ests, infos = [], []
        cand = model.candidates[i]
        if not cand.in_catalogue:
            out.append(0.0)
            continue
        for g in list(subsets) + (list(extra(cand)) if extra is not None else []):
            G, c, _ = g.weighted(weights)
            H = Ak.T @ G @ Ak
            info = float(np.trace(H))
            if info <= 0:
                continue
            d = np.linalg.lstsq(H, Ak.T @ (c - G @ theta), rcond=None)[0]
            ests.append(float((tk + d)[0]))
            infos.append(info)
        if not infos:
            out.append(0.0)
            continue
        ests, infos = np.array(ests), np.array(infos)
        ok = infos >= MIN_SUBSET_INFORMATION * infos.sum()
        dev = np.sqrt(np.sum(infos[ok] * (ests[ok] - tk[0]) ** 2) / infos[ok].sum())
        out.append(float(dev / max(abs(tk[0]), 1e-12)))
    return out


def select(layout: FeatureLayout, train: Grams, heldout: Grams, progress=None,
           candidates: list[Candidate] | None = None, subsets: list[Grams] | None = None,
           relevance=None, candidate_subsets=None) -> Selection:
    """Greedy forward selection with swaps and backward pruning (module docstring).

    Rigid-body and actuation candidates explain disjoint rows (Φ̃' and Γ), so each kind is
    selected separately with thresholds relative to its own nominal residual. The baseline
    (command-update sampling, candidates.py) is part of every model: the "nominal" residual is
    the one after it. With `subsets` (Grams of parts of the identification data), effects whose
    parameter is not consistent across them (consistency() > MAX_SPREAD) are rejected."""
    cands = list(layout.candidates if candidates is None else candidates)
    base = [layout.baseline]
    sigma, full_rms = noise_levels(layout, train, heldout)
    w = 1.0 / sigma ** 2
    Gt, ct, _ = train.weighted(w)
    Gh, ch, sh = heldout.weighted(w)
    nominal = _heldout_ss(fit_model(layout, base, Gt, ct), Gh, ch, sh)
    steps: list[Step] = []
    current: list[Candidate] = []
    for kind, dims in kind_dimensions(layout).items():
        prob = _Problem(layout, train, heldout, w, dims)
        fixed = [b for b in base if b.kind == kind]
        current += _select_kind(prob, [k for k in cands if k.kind == kind], steps, nominal, fixed, progress,
                                relevance)
    model = fit_model(layout, base + current, Gt, ct)
    rejected: list[tuple[str, float]] = []
    if (subsets or candidate_subsets) and current:
        spread = consistency(model, subsets or [], w, candidate_subsets)[len(base):]
        for k, sp in [(k, sp) for k, sp in zip(current, spread) if sp > MAX_SPREAD]:
            current.remove(k)
            rejected.append((k.label, sp))
            steps.append(Step(f"rejected {k.label}: its parameter varies by {sp:.0%} across contact "
                              "configurations and bags", 0.0, None, 0.0))
        model = fit_model(layout, base + current, Gt, ct)
    current_ss = _heldout_ss(model, Gh, ch, sh)
    # shares: explained part split by the drop-one cost of each effect
    explained = max(0.0, 1.0 - current_ss / nominal) if nominal > 0 else 0.0
    drop = []
    for k in current:
        m = fit_model(layout, base + [x for x in current if x is not k], Gt, ct)
        drop.append(max(0.0, _heldout_ss(m, Gh, ch, sh) - current_ss))
    total = sum(drop)
    shares = [explained * d / total if total > 0 else explained / len(current) for d in drop] if current else []
    order = list(np.argsort(shares)[::-1])
    model = fit_model(layout, base + [current[i] for i in order], Gt, ct)
    spread = (consistency(model, subsets or [], w, candidate_subsets)[len(base):]
              if (subsets or candidate_subsets) else [0.0] * len(order))
    return Selection(model=model, sigma=sigma, weights=w, nominal_ss=nominal, final_ss=current_ss,
                     shares=[shares[i] for i in order], steps=steps, full_fit_rms=full_rms,
                     spread=spread, rejected=rejected, raw_nominal_ss=float(sh), n_baseline=len(base))


# --- physical parameters ---------------------------------------------------------------------

def physical_parameters(model: Model) -> list[dict]:
    """Each candidate's parameters in the scenario's terms (DESIGN §5), e.g. {"value": 5.8}.

    Actuation parameters of one joint are converted together: with a = 1 − 1/g, b = o/g,
    c = T/g (candidates.py), g = 1/(1 − a), o = b g, T = c g.
    """
    gain = {}
    for cand in model.candidates:
        if cand.type == "torque_gain":
            a = float(model.params_of(cand)[0])
            gain[cand.joint] = 1.0 / (1.0 - a)
    out = []
    for cand in model.candidates:
        th = model.params_of(cand)
        if cand.type in ("joint_coulomb_friction", "joint_viscous_friction", "encoder_offset"):
            p = {"value": float(th[0])}
        elif cand.type == "base_imu_tilt":
            p = {"roll": float(th[0]), "pitch": float(th[1])}
        elif cand.type == "payload":
            m = float(th[0])
            com = (th[1:4] / m).tolist() if m > 1e-9 else [0.0, 0.0, 0.0]
            p = {"mass": m, "com": [float(x) for x in com]}
        elif cand.type == "link_mass_scale":
            p = {"value": 1.0 + float(th[0])}
        elif cand.type == "torque_gain":
            p = {"value": gain[cand.joint]}
        elif cand.type == "torque_offset":
            p = {"value": float(th[0]) * gain.get(cand.joint, 1.0)}
        elif cand.type == "actuator_lag":
            # a joint's own lag: c = T/g; the all-joint lag's column already carries 1/g_j (fit_model)
            p = {"time_constant": float(th[0]) * (gain.get(cand.joint, 1.0) if cand.joint else 1.0)}
        elif cand.type == "command_update_sampling":
            p = {"qd": float(th[0]), "qdd": float(th[1]), "udot": float(th[2])}
        elif not cand.in_catalogue:
            p = {"coefficients": [float(x) for x in th]}
        else:  # pragma: no cover
            raise ValueError(cand.type)
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


def bootstrap_std(selection: Selection, rows: Rows, fs: float = 250.0, n_boot: int = BOOTSTRAP,
                  seed: int = 0) -> list[dict]:
    """Standard deviation of each effect's physical parameters: moving-block bootstrap over time
    on the identification rows (blocks of BLOCK_SECONDS, resampled with replacement)."""
    model = selection.model
    if not model.candidates:
        return []
    layout = model.layout
    feats = np.unique(np.concatenate([np.asarray(c.features) for c in model.candidates]))
    n_s = len(rows.samples)
    block = max(1, int(round(BLOCK_SECONDS * fs)))
    n_blocks = max(1, int(np.ceil(n_s / block)))
    nf = layout.n_features
    Gb = np.zeros((n_blocks, len(feats), len(feats)))
    cb = np.zeros((n_blocks, len(feats)))
    n_rbd_dims = 6 + 3 * layout.robot.n_feet
    w = selection.weights
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
        fj = layout.actuation_feature(j, "lag") + np.arange(3)
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
    rng = np.random.default_rng(seed)
    base = physical_parameters(model)
    draws = []
    for _ in range(n_boot):
        pick = rng.integers(0, n_blocks, n_blocks)
        G = np.zeros((nf, nf))
        c = np.zeros(nf)
        G[np.ix_(feats, feats)] = Gb[pick].sum(axis=0)
        c[feats] = cb[pick].sum(axis=0)
        m = fit_model(layout, model.candidates, G, c)
        draws.append(_flatten(physical_parameters(m)))
    std = np.std(np.asarray(draws), axis=0, ddof=1) if n_boot > 1 else np.zeros_like(_flatten(base))
    return _unflatten(base, std)
