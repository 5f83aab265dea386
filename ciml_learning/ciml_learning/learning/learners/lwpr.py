"""Locally Weighted Projection Regression (LWPR), after Vijayakumar, D'Souza & Schaal,
"Incremental Online Learning in High Dimensions", Neural Computation 17(12), 2005.

No LWPR package exists on the registry, so this is ours: a numba port of the
algorithm, written from the paper and checked against the reference C library's
behaviour on the 2-D cross function (see the tests).

The model is a set of receptive fields (RFs) k, each with a centre c_k, a distance
metric D_k = M_kᵀM_k (M_k upper triangular) and a local linear model fitted by
incremental partial least squares (PLS) on the inputs relative to the RF's weighted
mean x̄_k:

    w_k(x) = exp(−½ (x − c_k)ᵀ D_k (x − c_k))                       Gaussian kernel
    ŷ_k(x) = β0_k + Σ_r β_k,r s_k,r,   s_k,r = u_k,rᵀ x_res,r          PLS projections
    ŷ(x)   = Σ_k w_k ŷ_k / Σ_k w_k                                   (paper eq. 4.1)

Per sample (x, y), every RF with w_k > w_cutoff is updated (paper Table 3):

    x_res,0 = x − x̄,  y_res,0 = y − β0
    u_r  ← λ_s u_r + w x_res,r−1 y_res,r−1      (SXresYres; λ_s = 1 − (1 − λ)/10, as in
                                                the reference library: slower for directions)
    s_r  = x_res,r−1ᵀ u_r / ‖u_r‖
    SS_r ← λ SS_r + w s_r²,  SR_r ← λ SR_r + w s_r y_res,r−1,  SZ_r ← λ SZ_r + w s_r x_res,r−1
    β_r  = SR_r / SS_r,  p_r = SZ_r / SS_r
    x_res,r = x_res,r−1 − s_r p_r,  y_res,r = y_res,r−1 − s_r β_r

with forgetting factors λ per projection that anneal from init_lambda to final_lambda
(λ ← τ λ + (1 − τ) λ_final). A projection is added when the last one still halves the
leave-one-out error (add_threshold) and it has seen enough data; at most
max_projections per RF.

The distance metric is adapted by stochastic gradient descent on the leave-one-out
cross-validation cost with a penalty on D (paper §3.2, Table 4):

    J = 1/W Σ w_i ‖y_i − ŷ_i,−i‖² + γ/N Σ_ij D_ij²
    M ← M − α ∂J/∂M,   ∂J/∂M ≈ (∂J₁/∂w)(∂w/∂M) + (w/W) ∂J₂/∂M
    ∂w/∂M_rl = −w (M dx)_r dx_l,   ∂J₂/∂M_rl = 4γ (M D)_rl

using the memory traces H and R of the paper for ∂J₁/∂w; the leverage
transient_multiplier of the reference library damps the first updates of a new RF,
and a step larger than 10 % of max|M| halves that entry's learning rate instead of
being taken. Meta-learning of the learning rates α (incremental delta-bar-delta,
paper §3.3) is optional (meta=True).

An RF is created at x when no RF has w > w_gen (copying the metric of the closest RF
when that one is trustworthy and w > 0.1 w_gen, else init_D); when two RFs both have
w > w_prune at a sample, the one with the larger leave-one-out error is pruned.

Prediction uncertainty (paper §4.5): each trustworthy RF contributes a predictive
variance σ_k² (1 + w_k Σ_r s_r² / SS_r), σ_k² its weighted leave-one-out MSE; the
global prediction is the mixture of the RFs plus a zero-mean *prior pseudo-field* of
constant weight prior_weight and variance prior_std²:

    ŷ = Σ_k w_k ŷ_k / (w₀ + Σ_k w_k)
    σ² = [w₀ σ₀² + Σ_k w_k (σ_k,pred² + ŷ_k²)] / (w₀ + Σ_k w_k) − ŷ²

so away from the data the prediction returns smoothly to zero (the nominal model)
and the std grows to prior_std. (The reference library instead returns 0 when no RF
is active and a confidence that diverges as Σ w → 0; the prior keeps σ finite and
bounded by the output scale.) The bias this adds where data exist is at most
w₀ / (w₀ + w_gen) (0.5 % with the defaults).

High-dimensional inputs (the 50-D rigid-body error models): the full metric has
n(n+1)/2 entries and an O(n²) update, so diag_only=True (the default above 10 inputs)
keeps a diagonal M (n entries, O(n) per RF) and max_projections stays small (the
local regressions of gait data are low-dimensional). The metric is stored packed:
entry p of M_k is M[prow[p], pcol[p]].

All state lives in preallocated arrays (capacity grows by doubling, up to max_rfs)
and the hot loops are numba @njit(cache=True) functions.
"""
from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from numba import njit

from ciml_learning.learning.learners.base import Learner, LearnerError

# ----------------------------------------------------------------------------------- layout
# hyper-parameter vector passed to the kernels
HP_W_GEN, HP_W_PRUNE, HP_W_CUTOFF, HP_INIT_LAMBDA, HP_FINAL_LAMBDA, HP_TAU_LAMBDA, HP_PENALTY, \
    HP_ADD_THRESHOLD, HP_INIT_S2, HP_META_RATE, HP_UPDATE_D, HP_META, HP_N_TRUST, HP_MAX_PROJ, \
    HP_INIT_PROJ, HP_PRED_CUTOFF, HP_PRIOR_WEIGHT, HP_MAX_RFS = range(18)
N_HP = 18

RF_FIELDS: tuple[tuple[str, str, str], ...] = (
    # name, per-RF shape ("", "n", "P", "R", "Rn"), dtype
    ("c", "n", "f8"),            # centre (normalised input units)
    ("M", "P", "f8"),            # packed upper-triangular Cholesky factor of D
    ("alpha", "P", "f8"),        # learning rates of M
    ("log_alpha", "P", "f8"),    # meta-learning: log α
    ("meta_h", "P", "f8"),       # meta-learning memory
    ("mean_x", "n", "f8"),       # weighted input mean x̄
    ("beta0", "", "f8"),         # weighted output mean β0
    ("n_reg", "", "i8"),         # number of PLS projections in use
    ("U", "Rn", "f8"),           # projection directions u_r (unit)
    ("P", "Rn", "f8"),           # regression loadings p_r
    ("beta", "R", "f8"),         # regression coefficients β_r
    ("SXresYres", "Rn", "f8"),   # Σ λ_s w x_res y_res
    ("SSs2", "R", "f8"),         # Σ λ w s²
    ("SSYres", "R", "f8"),       # Σ λ w s y_res
    ("SSXres", "Rn", "f8"),      # Σ λ w s x_res
    ("sum_w", "R", "f8"),        # Σ λ w
    ("n_data", "R", "f8"),       # Σ λ 1
    ("lambda", "R", "f8"),       # forgetting factors
    ("sum_e_cv2", "R", "f8"),    # Σ λ w e_cv² (leave-one-out error after projection r)
    ("sum_e2", "", "f8"),        # Σ λ w e² (fitted error)
    ("H", "R", "f8"),            # memory traces of the metric gradient (paper Table 4)
    ("r", "R", "f8"),
    ("trustworthy", "", "b1"),
)
RF_NAMES = tuple(f[0] for f in RF_FIELDS)


# rows of the scratch array the kernels work in (preallocated: numba allocations, not the
# arithmetic, dominated the per-sample cost of the small online models)
WK_XMZ, WK_XRES, WK_XPROJ, WK_S, WK_E_CV, WK_DJDM, WK_DDJ = range(7)
N_WK = 7


def workspace(n: int, n_packed: int, R: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Scratch for the kernels of a model with n inputs, n_packed metric entries and R projections:
    (work (N_WK × max(n, n_packed, R)), M_k and D_k as n × n matrices for a full metric, else 0 × 0)."""
    work = np.zeros((N_WK, max(n, n_packed, R)))
    full = n_packed != n
    size = n if full else 0
    return work, np.zeros((size, size)), np.zeros((size, size))


def metric_packing(n: int, diag_only: bool) -> tuple[np.ndarray, np.ndarray]:
    """(prow, pcol) of the packed metric entries: the diagonal, or the upper triangle."""
    if diag_only:
        idx = np.arange(n, dtype=np.int64)
        return idx, idx.copy()
    rows, cols = np.triu_indices(n)
    return rows.astype(np.int64), cols.astype(np.int64)


# ----------------------------------------------------------------------------------- kernels
# Per sample, the cost was numba's reference counting more than the arithmetic: a function that
# calls another one or can raise increfs and decrefs its array arguments (two atomic operations
# each), and so does every view (M[k]). So the kernels index in place, the per-field update is a
# sequence of leaf functions called from _update_sample, and error_model="numpy" drops the
# zero-divisor checks that could raise (no divisor here can be zero: the sums of weights start at
# 1e-10 and SS_r at init_S2 > 0, updated fields weigh > w_cutoff ≥ 0, ‖u‖ is tested) — the same
# arithmetic.
@njit(cache=True, error_model="numpy")
def _weight(M, k, prow, pcol, dx, z):
    """w = exp(−½ ‖M_k dx‖²); z ← M_k dx."""
    n = dx.shape[0]
    for i in range(n):
        z[i] = 0.0
    for p in range(M.shape[1]):
        z[prow[p]] += M[k, p] * dx[pcol[p]]
    d2 = 0.0
    for i in range(n):
        d2 += z[i] * z[i]
    return math.exp(-0.5 * d2)


@njit(cache=True, error_model="numpy")
def _project(U, P, k, R, work):
    """PLS projections s_r (→ work[WK_S]) of x − x̄ (work[WK_XMZ]) with RF k's directions U_k and
    loadings P_k (work[WK_XPROJ]: scratch)."""
    n = U.shape[2]
    for i in range(n):
        work[WK_XPROJ, i] = work[WK_XMZ, i]
    for r in range(R):
        acc = 0.0
        for i in range(n):
            acc += U[k, r, i] * work[WK_XPROJ, i]
        work[WK_S, r] = acc
        if r + 1 < R:
            for i in range(n):
                work[WK_XPROJ, i] -= acc * P[k, r, i]


@njit(cache=True, error_model="numpy")
def _init_rf(k, x, y, template, hp, initM, initAlpha,
             c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta, SXresYres, SSs2, SSYres,
             SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust):
    n = x.shape[0]
    Rmax = U.shape[1]
    for i in range(n):
        c[k, i] = x[i]
        mean_x[k, i] = x[i]
    for p in range(M.shape[1]):
        if template >= 0:
            M[k, p] = M[template, p]
            alpha[k, p] = alpha[template, p]
        else:
            M[k, p] = initM[p]
            alpha[k, p] = initAlpha[p]
        log_alpha[k, p] = math.log(alpha[k, p])
        meta_h[k, p] = 0.0
    beta0[k] = y
    n_reg[k] = min(int(hp[HP_INIT_PROJ]), Rmax)
    for r in range(Rmax):
        for i in range(n):
            U[k, r, i] = 0.0
            P[k, r, i] = 0.0
            SXresYres[k, r, i] = 0.0
            SSXres[k, r, i] = 0.0
        U[k, r, r % n] = 1.0
        P[k, r, r % n] = 1.0
        beta[k, r] = 0.0
        SSs2[k, r] = hp[HP_INIT_S2]
        SSYres[k, r] = 0.0
        sum_w[k, r] = 1e-10
        n_data[k, r] = 1e-10
        lam[k, r] = hp[HP_INIT_LAMBDA]
        sum_e_cv2[k, r] = 0.0
        H[k, r] = 0.0
        rr[k, r] = 0.0
    sum_e2[k] = 0.0
    trust[k] = False


@njit(cache=True, error_model="numpy")
def _copy_rf(dst, src, c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta, SXresYres, SSs2,
             SSYres, SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust):
    c[dst] = c[src]
    M[dst] = M[src]
    alpha[dst] = alpha[src]
    log_alpha[dst] = log_alpha[src]
    meta_h[dst] = meta_h[src]
    mean_x[dst] = mean_x[src]
    beta0[dst] = beta0[src]
    n_reg[dst] = n_reg[src]
    U[dst] = U[src]
    P[dst] = P[src]
    beta[dst] = beta[src]
    SXresYres[dst] = SXresYres[src]
    SSs2[dst] = SSs2[src]
    SSYres[dst] = SSYres[src]
    SSXres[dst] = SSXres[src]
    sum_w[dst] = sum_w[src]
    n_data[dst] = n_data[src]
    lam[dst] = lam[src]
    sum_e_cv2[dst] = sum_e_cv2[src]
    sum_e2[dst] = sum_e2[src]
    H[dst] = H[src]
    rr[dst] = rr[src]
    trust[dst] = trust[src]


@njit(cache=True, error_model="numpy")
def _metric_matrices(M, k, prow, pcol, Md, D):
    """M_k unpacked into Md and D_k = M_kᵀM_k (a full metric's gradient needs both)."""
    Md[:, :] = 0.0
    for p in range(M.shape[1]):
        Md[prow[p], pcol[p]] = M[k, p]
    np.dot(Md.T, Md, D)  # the same BLAS product as Md.T @ Md, into preallocated D


@njit(cache=True, error_model="numpy")
def _update_metric(k, w, dx, z, R, e_cv, e, hp, prow, pcol, work, Md, D, M, alpha, log_alpha, meta_h,
                   SSs2, sum_w, lam, sum_e_cv2, sum_e2, H, rr):
    """One stochastic leave-one-out gradient step on M_k (paper §3.2, Table 4); the projections s_r
    of the sample are in work[WK_S], a full metric's Md and D from _metric_matrices."""
    n = dx.shape[0]
    nP = M.shape[1]
    penalty = hp[HP_PENALTY]
    meta = hp[HP_META] > 0.0
    W = sum_w[k, 0]
    E = sum_e_cv2[k, R - 1]
    tm = (sum_e2[k] / (E + 1e-10)) ** 4  # transient multiplier (reference library heuristic)
    if tm > 1.0:
        tm = 1.0
    h = 0.0
    for r in range(R):
        h += work[WK_S, r] * work[WK_S, r] / SSs2[k, r]
    h *= w
    e_cv2 = e_cv * e_cv
    sHe = 0.0
    sPr = 0.0
    for r in range(R):
        Ps = work[WK_S, r] / SSs2[k, r]
        sHe += Ps * e * H[k, r]
        sPr += Ps * Ps * rr[k, r]
    dJ1dw = -E / (W * W) + (e_cv2 - 2.0 * sHe - 2.0 * sPr) / W
    dJ1J1dwdw = 0.0
    if meta:
        sPse = 0.0
        for r in range(R):
            sPse += work[WK_S, r] * (work[WK_S, r] / SSs2[k, r]) * e
        t1 = 0.0
        t2 = 0.0
        for r in range(R):
            Ps = work[WK_S, r] / SSs2[k, r]
            Pse = Ps * e
            t1 += (-Pse / W - 2.0 * Ps * sPse) * H[k, r]
            t2 += Pse * H[k, r]
        dJ1J1dwdw = (-e_cv2 / (W * W) - 2.0 / W * t1 + 2.0 / W * e * e * h / w
                     - (e_cv2 - 2.0 * t2) / (W * W) + 2.0 * E / (W * W * W))
    diag = nP == n
    maxM = 0.0
    for p in range(nP):
        if abs(M[k, p]) > maxM:
            maxM = abs(M[k, p])
    for p in range(nP):
        rw = prow[p]
        cl = pcol[p]
        mk = M[k, p]
        dwdM = -w * z[rw] * dx[cl]
        if diag:
            MD = mk * mk * mk
            d2J2 = 4.0 * penalty * 3.0 * mk * mk
        else:
            MD = 0.0
            rown = 0.0
            for j in range(n):
                MD += Md[rw, j] * D[j, cl]
                rown += Md[rw, j] * Md[rw, j]
            d2J2 = 4.0 * penalty * (D[cl, cl] + mk * mk + rown)
        work[WK_DJDM, p] = dwdM * dJ1dw + w / W * 4.0 * penalty * MD
        if meta:
            dwwdMdM = dwdM * dwdM / w - w * dx[cl] * dx[cl]
            work[WK_DDJ, p] = dwwdMdM * dJ1dw + dwdM * dwdM * dJ1J1dwdw + w / W * d2J2
            aux = hp[HP_META_RATE] * tm * work[WK_DJDM, p] * meta_h[k, p]
            if aux > 0.1:
                aux = 0.1
            elif aux < -0.1:
                aux = -0.1
            b = log_alpha[k, p] - aux
            if b > 10.0:
                b = 10.0
            elif b < -10.0:
                b = -10.0
            log_alpha[k, p] = b
            alpha[k, p] = math.exp(b)
    for p in range(nP):
        delta = alpha[k, p] * work[WK_DJDM, p] * tm
        if abs(delta) > 0.1 * maxM:  # too large a step: halve that learning rate instead
            alpha[k, p] *= 0.5
            log_alpha[k, p] = math.log(alpha[k, p])
        else:
            M[k, p] -= delta
    if meta:
        for p in range(nP):
            aux = 1.0 - alpha[k, p] * work[WK_DDJ, p] * tm
            if aux < 0.0:
                aux = 0.0
            meta_h[k, p] = meta_h[k, p] * aux - alpha[k, p] * work[WK_DJDM, p] * tm
    if h < 0.999:
        for r in range(R):
            H[k, r] = lam[k, r] * H[k, r] + (w / (1.0 - h)) * work[WK_S, r] * e_cv * tm
            rr[k, r] = lam[k, r] * rr[k, r] + (w * w * e_cv2 / (1.0 - h)) * work[WK_S, r] * work[WK_S, r] * tm


@njit(cache=True, error_model="numpy")
def _update_means(k, x, y, w, work, mean_x, beta0, sum_w, lam):
    """Weighted means x̄_k, β0_k with the sample at weight w; x − x̄ into work[WK_XMZ]; returns y − β0."""
    n = x.shape[0]
    sw = sum_w[k, 0] * lam[k, 0]
    denom = sw + w
    for i in range(n):
        mean_x[k, i] = (sw * mean_x[k, i] + w * x[i]) / denom
        work[WK_XMZ, i] = x[i] - mean_x[k, i]
    beta0[k] = (sw * beta0[k] + w * y) / denom
    return y - beta0[k]


@njit(cache=True, error_model="numpy")
def _update_regression(k, w, ymz, work, n_reg, U, P, beta, SXresYres, SSs2, SSYres, SSXres, sum_w, n_data, lam,
                       sum_e_cv2, sum_e2):
    """Incremental PLS of field k (paper Table 3) on x − x̄ (work[WK_XMZ]) and y − β0 (ymz), after
    _project put the leave-one-out projections in work[WK_S]; returns the fitted residual e."""
    n = U.shape[2]
    R = n_reg[k]
    # leave-one-out (prediction before the update) residuals after each projection
    yr = ymz
    for r in range(R):
        yr -= beta[k, r] * work[WK_S, r]
        work[WK_E_CV, r] = yr
    # incremental PLS with forgetting
    for i in range(n):
        work[WK_XRES, i] = work[WK_XMZ, i]
    yres = ymz
    for r in range(R):
        lr = lam[k, r]
        ls = 1.0 - (1.0 - lr) / 10.0
        nrm = 0.0
        for i in range(n):
            v = ls * SXresYres[k, r, i] + w * yres * work[WK_XRES, i]
            SXresYres[k, r, i] = v
            nrm += v * v
        if nrm > 1e-300:
            nrm = math.sqrt(nrm)
            for i in range(n):
                U[k, r, i] = SXresYres[k, r, i] / nrm
        sr = 0.0
        for i in range(n):
            sr += U[k, r, i] * work[WK_XRES, i]
        work[WK_S, r] = sr
        SSs2[k, r] = lr * SSs2[k, r] + w * sr * sr
        SSYres[k, r] = lr * SSYres[k, r] + w * sr * yres
        beta[k, r] = SSYres[k, r] / SSs2[k, r]
        for i in range(n):
            SSXres[k, r, i] = lr * SSXres[k, r, i] + w * sr * work[WK_XRES, i]
            P[k, r, i] = SSXres[k, r, i] / SSs2[k, r]
            work[WK_XRES, i] -= sr * P[k, r, i]
        yres -= sr * beta[k, r]
    e = yres
    for r in range(R):
        lr = lam[k, r]
        sum_w[k, r] = lr * sum_w[k, r] + w
        n_data[k, r] = lr * n_data[k, r] + 1.0
        sum_e_cv2[k, r] = lr * sum_e_cv2[k, r] + w * work[WK_E_CV, r] * work[WK_E_CV, r]
    sum_e2[k] = lam[k, R - 1] * sum_e2[k] + w * e * e
    return e


@njit(cache=True, error_model="numpy")
def _update_schedule(k, hp, n_reg, U, sum_w, n_data, lam, sum_e_cv2, trust):
    """After a field's update: anneal its forgetting factors, add a projection when the last one still
    halves the leave-one-out error, trust it once it has seen n_trust (discounted) samples."""
    R = n_reg[k]
    Rmax = U.shape[1]
    tau = hp[HP_TAU_LAMBDA]
    for r in range(R):
        lam[k, r] = tau * lam[k, r] + hp[HP_FINAL_LAMBDA] * (1.0 - tau)
    if R >= 2 and R < Rmax and R < int(hp[HP_MAX_PROJ]):
        mse_r = sum_e_cv2[k, R - 1] / sum_w[k, R - 1] + 1e-10
        mse_r1 = sum_e_cv2[k, R - 2] / sum_w[k, R - 2] + 1e-10
        if (mse_r / mse_r1 < hp[HP_ADD_THRESHOLD] and n_data[k, R - 1] / n_data[k, 0] > 0.99
                and n_data[k, R - 1] * (1.0 - lam[k, R - 1]) > 0.5):
            n_reg[k] = R + 1
            # its slot was initialised by _init_rf and never touched since
    if n_data[k, 0] > hp[HP_N_TRUST]:
        trust[k] = True


@njit(cache=True, error_model="numpy")
def _update_sample(x, y, hp, initM, initAlpha, prow, pcol, counts, moments, dx, z, work, Md, D,
                   c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta, SXresYres, SSs2, SSYres,
                   SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust):
    """One LWPR update (all RFs, creation, pruning); False if the arrays are full (grow first)."""
    n = x.shape[0]
    n_rf = counts[0]
    max_rfs = int(hp[HP_MAX_RFS])
    if n_rf >= c.shape[0] and n_rf < max_rfs:
        return False
    moments[0] += 1.0
    moments[1] += y * y
    w1 = 0.0
    i1 = -1
    w2 = 0.0
    i2 = -1
    created = False
    for k in range(n_rf + 1):  # the fields, then (k = n_rf) a new one if none is activated enough
        if k < n_rf:
            for i in range(n):
                dx[i] = x[i] - c[k, i]
            w = _weight(M, k, prow, pcol, dx, z)
            if w > w1:
                w2 = w1
                i2 = i1
                w1 = w
                i1 = k
            elif w > w2:
                w2 = w
                i2 = k
            if w <= hp[HP_W_CUTOFF]:
                continue
        elif w1 <= hp[HP_W_GEN] and n_rf < max_rfs:
            template = -1
            if i1 >= 0 and w1 > 0.1 * hp[HP_W_GEN] and trust[i1]:
                template = i1
            _init_rf(k, x, y, template, hp, initM, initAlpha,
                     c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta, SXresYres, SSs2, SSYres,
                     SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust)
            for i in range(n):
                dx[i] = 0.0
                z[i] = 0.0
            w = 1.0
            created = True
        else:
            break
        # update field k at weight w: means, PLS, metric, schedule (the leaves above, in this order)
        ymz = _update_means(k, x, y, w, work, mean_x, beta0, sum_w, lam)
        _project(U, P, k, n_reg[k], work)
        e = _update_regression(k, w, ymz, work, n_reg, U, P, beta, SXresYres, SSs2, SSYres, SSXres, sum_w, n_data,
                               lam, sum_e_cv2, sum_e2)
        if hp[HP_UPDATE_D] > 0.0 and n_data[k, 0] > hp[HP_N_TRUST]:
            if M.shape[1] != n:
                _metric_matrices(M, k, prow, pcol, Md, D)
            _update_metric(k, w, dx, z, n_reg[k], work[WK_E_CV, n_reg[k] - 1], e, hp, prow, pcol, work, Md, D, M,
                           alpha, log_alpha, meta_h, SSs2, sum_w, lam, sum_e_cv2, sum_e2, H, rr)
        _update_schedule(k, hp, n_reg, U, sum_w, n_data, lam, sum_e_cv2, trust)
    if created:
        counts[0] = n_rf + 1
        counts[1] += 1
    elif w2 > hp[HP_W_PRUNE] and i2 >= 0:
        # two RFs overlap too much: prune the one with the larger leave-one-out error
        ra = n_reg[i1] - 1
        rb = n_reg[i2] - 1
        ea = sum_e_cv2[i1, ra] / sum_w[i1, ra]
        eb = sum_e_cv2[i2, rb] / sum_w[i2, rb]
        victim = i1 if ea > eb else i2
        last = n_rf - 1
        if victim != last:
            _copy_rf(victim, last, c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta,
                     SXresYres, SSs2, SSYres, SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust)
        counts[0] = n_rf - 1
        counts[2] += 1
    return True


@njit(cache=True, error_model="numpy")
def _update_batch(X, Y, start, hp, initM, initAlpha, prow, pcol, counts, moments,
                  c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta, SXresYres, SSs2, SSYres,
                  SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust):
    """Update with rows start.. of (X, Y) (normalised). counts = [n_rf, added, pruned];
    moments = [samples seen, Σ y²] (sequential sums: batch and one-by-one updates agree
    to the last bit).

    Returns the index of the first row not processed (== len(X) unless capacity ran out).
    """
    n = X.shape[1]
    dx = np.empty(n)
    z = np.empty(n)
    work = np.empty((N_WK, max(n, M.shape[1], U.shape[1])))
    Md = np.zeros((n, n))
    D = np.zeros((n, n))
    for t in range(start, X.shape[0]):
        if not _update_sample(X[t], Y[t], hp, initM, initAlpha, prow, pcol, counts, moments, dx, z, work, Md, D,
                              c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta, SXresYres, SSs2,
                              SSYres, SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust):
            return t  # the caller grows the arrays and calls again
    return X.shape[0]


@njit(cache=True, error_model="numpy")
def _update_one(x, y, hp, initM, initAlpha, prow, pcol, counts, moments, dx, z, work, Md, D,
                c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta, SXresYres, SSs2, SSYres,
                SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust):
    """Single-sample update (online fast path); False if the arrays must grow first."""
    return _update_sample(x, y, hp, initM, initAlpha, prow, pcol, counts, moments, dx, z, work, Md, D,
                          c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta, SXresYres, SSs2,
                          SSYres, SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust)


@njit(cache=True, error_model="numpy")
def _update_stack(X, Y, learn, hp, initM, initAlpha, prow, pcol, counts, moments, dx, z, work, Md, D,
                  c, M, alpha, log_alpha, meta_h, mean_x, beta0, n_reg, U, P, beta, SXresYres, SSs2, SSYres,
                  SSXres, sum_w, n_data, lam, sum_e_cv2, sum_e2, H, rr, trust):
    """One sample into each model g of a stack (LWPRStack) with learn[g]: normalised input X[g], target
    Y[g]. Returns −1, or — before anything changed — the first such g whose arrays are full."""
    G = X.shape[0]
    capacity = c.shape[1]
    for g in range(G):
        if learn[g] and capacity <= counts[g, 0] < int(hp[g, HP_MAX_RFS]):
            return g
    for g in range(G):
        if learn[g]:
            _update_sample(X[g], Y[g], hp[g], initM[g], initAlpha[g], prow[g], pcol[g], counts[g], moments[g],
                           dx, z, work, Md, D, c[g], M[g], alpha[g], log_alpha[g], meta_h[g], mean_x[g], beta0[g],
                           n_reg[g], U[g], P[g], beta[g], SXresYres[g], SSs2[g], SSYres[g], SSXres[g], sum_w[g],
                           n_data[g], lam[g], sum_e_cv2[g], sum_e2[g], H[g], rr[g], trust[g])
    return -1


@njit(cache=True, error_model="numpy")
def _predict_point(x, hp, prior_var, with_var, prow, pcol, n_rf, dx, z, work,
                   c, M, mean_x, beta0, n_reg, U, P, beta, SSs2, sum_w, sum_e_cv2, trust):
    """(mean, variance) at x: mixture of the trustworthy RFs and the zero-mean prior pseudo-field."""
    n = x.shape[0]
    w0 = hp[HP_PRIOR_WEIGHT]
    cutoff = hp[HP_PRED_CUTOFF]
    sw = w0
    sy = 0.0
    sy2 = w0 * prior_var
    for k in range(n_rf):
        if not trust[k]:
            continue
        for i in range(n):
            dx[i] = x[i] - c[k, i]
        w = _weight(M, k, prow, pcol, dx, z)
        if w <= cutoff:
            continue
        for i in range(n):
            work[WK_XMZ, i] = x[i] - mean_x[k, i]
        R = n_reg[k]
        _project(U, P, k, R, work)
        yk = beta0[k]
        for r in range(R):
            yk += beta[k, r] * work[WK_S, r]
        sw += w
        sy += w * yk
        if with_var:
            lev = 0.0
            for r in range(R):
                lev += work[WK_S, r] * work[WK_S, r] / SSs2[k, r]
            sigma2 = sum_e_cv2[k, R - 1] / sum_w[k, R - 1]
            sy2 += w * (sigma2 * (1.0 + w * lev) + yk * yk)
    mean = sy / sw
    var = 0.0
    if with_var:
        var = sy2 / sw - mean * mean
        if var < 0.0:
            var = 0.0
    return mean, var


@njit(cache=True, error_model="numpy")
def _predict_batch(X, hp, prior_var, with_var, prow, pcol, n_rf,
                   c, M, mean_x, beta0, n_reg, U, P, beta, SSs2, sum_w, sum_e_cv2, trust, out_mean, out_var):
    n = X.shape[1]
    dx = np.empty(n)
    z = np.empty(n)
    work = np.empty((N_WK, max(n, M.shape[1], U.shape[1])))
    for t in range(X.shape[0]):
        m, v = _predict_point(X[t], hp, prior_var, with_var, prow, pcol, n_rf, dx, z, work,
                              c, M, mean_x, beta0, n_reg, U, P, beta, SSs2, sum_w, sum_e_cv2, trust)
        out_mean[t] = m
        if with_var:
            out_var[t] = v


@njit(cache=True, error_model="numpy")
def _predict_one(x, hp, prior_var, prow, pcol, counts, dx, z, work,
                 c, M, mean_x, beta0, n_reg, U, P, beta, SSs2, sum_w, sum_e_cv2, trust):
    return _predict_point(x, hp, prior_var, True, prow, pcol, counts[0], dx, z, work, c, M, mean_x, beta0, n_reg,
                          U, P, beta, SSs2, sum_w, sum_e_cv2, trust)


@njit(cache=True, error_model="numpy")
def _predict_stack(X, active, prior_fixed, norm_out, hp, prow, pcol, counts, moments, dx, z, work,
                   c, M, mean_x, beta0, n_reg, U, P, beta, SSs2, sum_w, sum_e_cv2, trust, out_mean, out_std):
    """(mean, std) of each model g of a stack with active[g] at its normalised input X[g], in output
    units (× norm_out[g]), as LWPR.predict_one: the prior variance is prior_fixed[g], or where that is
    NaN (no prior_std) the mean y² seen (LWPR.prior_var_)."""
    for g in range(X.shape[0]):
        if not active[g]:
            continue
        prior_var = prior_fixed[g]
        if math.isnan(prior_var):
            seen = int(moments[g, 0])
            prior_var = max(moments[g, 1] / seen, 1e-12) if seen else 1.0
        m, v = _predict_point(X[g], hp[g], prior_var, True, prow[g], pcol[g], counts[g, 0], dx, z, work, c[g], M[g],
                              mean_x[g], beta0[g], n_reg[g], U[g], P[g], beta[g], SSs2[g], sum_w[g], sum_e_cv2[g],
                              trust[g])
        out_mean[g] = m * norm_out[g]
        out_std[g] = math.sqrt(v) * norm_out[g]


# ----------------------------------------------------------------------------------- learner
class LWPR(Learner):
    """Locally weighted projection regression, one output (module docstring).

    Hyper-parameters (inputs in units of norm_in, outputs in units of norm_out):
        init_D: initial distance metric of new RFs — scalar (×I), (n,) diagonal or (n, n).
        diag_only: adapt a diagonal metric only; None: True for more than 10 inputs.
        init_alpha: initial learning rate of the metric.
        w_gen: create an RF where no RF is activated above this.
        w_prune: prune one of two RFs both activated above this (1.0 disables pruning).
        w_cutoff: RFs with a smaller activation are not updated by a sample.
        init_lambda, final_lambda, tau_lambda: forgetting factor schedule.
        penalty: γ of the metric penalty (smoothness: larger → wider RFs).
        add_threshold: add a PLS projection when the last one's error ratio is below this.
        max_projections: PLS projections per RF at most (None: n inputs).
        init_projections: projections of a new RF (2, as the reference library).
        update_D, meta, meta_rate: metric adaptation and meta-learning of its rates.
        norm_in: input scales (x/norm_in is used): None → 1, "auto" → std of the first
            data seen (floored), or an array of n scales.
        norm_out: output scale.
        n_trust: an RF predicts and adapts its metric after this many (discounted)
            samples; None → 2·n_inputs, capped at 50.
        max_rfs: capacity limit (memory bound for online use); no RF is added beyond.
        prior_weight, prior_std: the zero-mean prior pseudo-field (None: prior_std is the
            RMS of the targets seen).
        pred_cutoff: RFs with a smaller activation are skipped in prediction.
        n_epochs, shuffle, random_state: passes over the data in fit().
    """

    name: ClassVar[str] = "lwpr"
    supports_partial_fit: ClassVar[bool] = True

    def __init__(
        self,
        init_D: float | list = 25.0,
        diag_only: bool | None = None,
        init_alpha: float = 50.0,
        w_gen: float = 0.1,
        w_prune: float = 0.9,
        w_cutoff: float = 1e-3,
        init_lambda: float = 0.999,
        final_lambda: float = 0.99999,
        tau_lambda: float = 0.9999,
        penalty: float = 1e-6,
        add_threshold: float = 0.5,
        max_projections: int | None = None,
        init_projections: int = 2,
        init_S2: float = 1e-10,
        update_D: bool = True,
        meta: bool = False,
        meta_rate: float = 250.0,
        norm_in: Any = None,
        norm_out: float = 1.0,
        n_trust: float | None = None,
        max_rfs: int = 1000,
        prior_weight: float = 1e-3,
        prior_std: float | None = None,
        pred_cutoff: float = 1e-5,
        n_epochs: int = 1,
        shuffle: bool = False,
        random_state: int = 0,
    ) -> None:
        self.init_D = init_D
        self.diag_only = diag_only
        self.init_alpha = init_alpha
        self.w_gen = w_gen
        self.w_prune = w_prune
        self.w_cutoff = w_cutoff
        self.init_lambda = init_lambda
        self.final_lambda = final_lambda
        self.tau_lambda = tau_lambda
        self.penalty = penalty
        self.add_threshold = add_threshold
        self.max_projections = max_projections
        self.init_projections = init_projections
        self.init_S2 = init_S2
        self.update_D = update_D
        self.meta = meta
        self.meta_rate = meta_rate
        self.norm_in = norm_in
        self.norm_out = norm_out
        self.n_trust = n_trust
        self.max_rfs = max_rfs
        self.prior_weight = prior_weight
        self.prior_std = prior_std
        self.pred_cutoff = pred_cutoff
        self.n_epochs = n_epochs
        self.shuffle = shuffle
        self.random_state = random_state
        self._validate_params()

    def _validate_params(self) -> None:
        checks = {
            "w_gen": 0.0 < self.w_gen < 1.0,
            "w_prune": 0.0 < self.w_prune <= 1.0,
            "w_cutoff": 0.0 <= self.w_cutoff < self.w_gen,
            "init_lambda": 0.0 < self.init_lambda <= 1.0,
            "final_lambda": 0.0 < self.final_lambda <= 1.0,
            "tau_lambda": 0.0 <= self.tau_lambda <= 1.0,
            "init_alpha": self.init_alpha > 0.0,
            "init_S2": self.init_S2 > 0.0,
            "penalty": self.penalty >= 0.0,
            "norm_out": self.norm_out > 0.0,
            "max_rfs": int(self.max_rfs) >= 1,
            "prior_weight": self.prior_weight > 0.0,
            "init_projections": int(self.init_projections) >= 1,
            "n_epochs": int(self.n_epochs) >= 1,
        }
        bad = [k for k, ok in checks.items() if not ok]
        if bad:
            raise LearnerError(f"invalid LWPR hyper-parameter(s) {bad}: {[getattr(self, k) for k in bad]}")

    # --------------------------------------------------------------- setup
    def _setup(self, n: int, X: np.ndarray | None) -> None:
        """Allocate an empty model for n inputs (called by the first fit/partial_fit)."""
        diag = self.diag_only if self.diag_only is not None else n > 10
        if isinstance(self.norm_in, str):
            if self.norm_in != "auto":
                raise LearnerError(f"norm_in must be None, 'auto' or an array, got {self.norm_in!r}")
            scale = np.std(X, axis=0) if X is not None and len(X) > 1 else np.ones(n)
            scale = np.where(scale > 1e-9, scale, 1.0)
        elif self.norm_in is None:
            scale = np.ones(n)
        else:
            scale = np.asarray(self.norm_in, dtype=float).reshape(-1)
            if scale.shape != (n,) or np.any(scale <= 0) or not np.all(np.isfinite(scale)):
                raise LearnerError(f"norm_in must be {n} positive scales, got {self.norm_in!r}")
        D0 = np.asarray(self.init_D, dtype=float)
        if D0.ndim == 0:
            D0 = float(D0) * np.eye(n)
        elif D0.ndim == 1:
            D0 = np.diag(D0)
        if D0.shape != (n, n) or not np.all(np.isfinite(D0)):
            raise LearnerError(f"init_D must be a scalar, {n} values or {n}×{n}, got shape {D0.shape}")
        try:
            M0 = np.linalg.cholesky(D0).T  # upper triangular, D = MᵀM
        except np.linalg.LinAlgError as err:
            raise LearnerError("init_D must be symmetric positive definite") from err
        prow, pcol = metric_packing(n, diag)
        R = n if self.max_projections is None else max(1, min(int(self.max_projections), n))
        self.n_features_in_ = n
        self.norm_in_ = scale
        self.diag_only_ = bool(diag)
        self._prow, self._pcol = prow, pcol
        self._initM = np.ascontiguousarray(M0[prow, pcol])
        self._initAlpha = np.full(len(prow), float(self.init_alpha))
        self._R = R
        self._hp = self._hyper_vector(n)
        self._dx, self._z = np.zeros(n), np.zeros(n)
        self._work, self._Md, self._D = workspace(n, len(prow), R)
        self._counts = np.zeros(3, dtype=np.int64)
        self._moments = np.zeros(2)
        self._allocate(min(16, int(self.max_rfs)))

    def _hyper_vector(self, n: int) -> np.ndarray:
        hp = np.zeros(N_HP)
        hp[HP_W_GEN] = self.w_gen
        hp[HP_W_PRUNE] = self.w_prune if self.w_prune < 1.0 else np.inf
        hp[HP_W_CUTOFF] = self.w_cutoff
        hp[HP_INIT_LAMBDA] = self.init_lambda
        hp[HP_FINAL_LAMBDA] = self.final_lambda
        hp[HP_TAU_LAMBDA] = self.tau_lambda
        hp[HP_PENALTY] = self.penalty
        hp[HP_ADD_THRESHOLD] = self.add_threshold
        hp[HP_INIT_S2] = self.init_S2
        hp[HP_META_RATE] = self.meta_rate
        hp[HP_UPDATE_D] = float(bool(self.update_D))
        hp[HP_META] = float(bool(self.meta))
        hp[HP_N_TRUST] = self.n_trust if self.n_trust is not None else min(2.0 * n, 50.0)
        hp[HP_MAX_PROJ] = self._R
        hp[HP_INIT_PROJ] = min(int(self.init_projections), self._R)
        hp[HP_PRED_CUTOFF] = self.pred_cutoff
        hp[HP_PRIOR_WEIGHT] = self.prior_weight
        hp[HP_MAX_RFS] = int(self.max_rfs)
        return hp

    def _shape(self, kind: str, K: int) -> tuple[int, ...]:
        n, nP, R = self.n_features_in_, len(self._prow), self._R
        return {"": (K,), "n": (K, n), "P": (K, nP), "R": (K, R), "Rn": (K, R, n)}[kind]

    def _allocate(self, K: int, old: dict[str, np.ndarray] | None = None, n_used: int = 0) -> None:
        rf = {}
        for name, kind, dt in RF_FIELDS:
            a = np.zeros(self._shape(kind, K), dtype=dt)
            if old is not None:
                a[:n_used] = old[name][:n_used]
            rf[name] = a
        self._bind(rf, self._counts.copy(), self._moments.copy())

    def _bind(self, rf: dict[str, np.ndarray], counts: np.ndarray, moments: np.ndarray) -> None:
        """Use these state arrays (own ones, or views of an LWPRStack's) from now on."""
        self.rf_ = rf
        self._counts, self._moments = counts, moments
        self._rf_args = tuple(rf[name] for name in RF_NAMES)
        self._update_args = (self._hp, self._initM, self._initAlpha, self._prow, self._pcol, self._counts,
                             self._moments, self._dx, self._z, self._work, self._Md, self._D, *self._rf_args)
        self._predict_args = (self._prow, self._pcol, self._counts, self._dx, self._z, self._work,
                              *(rf[k] for k in ("c", "M", "mean_x", "beta0", "n_reg", "U", "P", "beta", "SSs2",
                                                "sum_w", "sum_e_cv2", "trustworthy")))

    def _grow(self) -> None:
        K = self.rf_["c"].shape[0]
        self._allocate(min(2 * K, int(self.max_rfs)), self.rf_, int(self._counts[0]))

    # --------------------------------------------------------------- learning
    def fit(self, X: np.ndarray, y: np.ndarray) -> "LWPR":
        """Learn from scratch: n_epochs passes of partial_fit over (X, y); returns self."""
        X, y = self._check_Xy(X, y)
        self._setup(X.shape[1], X)
        rng = np.random.default_rng(self.random_state)
        for _ in range(int(self.n_epochs)):
            if self.shuffle:
                order = rng.permutation(len(X))
                self._partial_fit(X[order], y[order])
            else:
                self._partial_fit(X, y)
        return self

    def partial_fit(self, X: np.ndarray, y: np.ndarray) -> "LWPR":
        """Incremental update, one sample after the other in the order given; returns self.

        A single sample may be passed as X of shape (n,) and y scalar."""
        X, y = self._check_Xy(X, y, getattr(self, "n_features_in_", None))
        if not self.is_fitted:
            self._setup(X.shape[1], X)
        self._partial_fit(X, y)
        return self

    def _partial_fit(self, X: np.ndarray, y: np.ndarray) -> None:
        Xn = np.ascontiguousarray(X / self.norm_in_)
        yn = np.ascontiguousarray(y / self.norm_out)
        start = 0
        while start < len(Xn):
            start = _update_batch(Xn, yn, start, self._hp, self._initM, self._initAlpha, self._prow, self._pcol,
                                  self._counts, self._moments, *self._rf_args)
            if start < len(Xn):
                self._grow()

    def update(self, x: np.ndarray, y: float) -> None:
        """Fast single-sample partial_fit for online use: x (n,) finite, y finite (unchecked)."""
        if not self.is_fitted:
            self.partial_fit(np.asarray(x, float)[None, :], np.array([y], float))
            return
        xn = np.asarray(x, dtype=float) / self.norm_in_
        yn = float(y) / self.norm_out
        if not _update_one(xn, yn, *self._update_args):
            self._grow()
            _update_one(xn, yn, *self._update_args)

    # --------------------------------------------------------------- prediction
    @property
    def n_receptive_fields(self) -> int:
        return int(self._counts[0]) if self.is_fitted else 0

    @property
    def n_added_(self) -> int:
        """Receptive fields created so far."""
        return int(self._counts[1]) if self.is_fitted else 0

    @property
    def n_pruned_(self) -> int:
        """Receptive fields pruned so far."""
        return int(self._counts[2]) if self.is_fitted else 0

    @property
    def n_samples_seen_(self) -> int:
        return int(self._moments[0]) if self.is_fitted else 0

    @property
    def sum_y2_(self) -> float:
        """Σ y² of the (normalised) targets seen: the prior variance is its mean."""
        return float(self._moments[1]) if self.is_fitted else 0.0

    @property
    def prior_var_(self) -> float:
        """Variance of the prior pseudo-field (normalised output units)."""
        if self.prior_std is not None:
            return (float(self.prior_std) / self.norm_out) ** 2
        n = self.n_samples_seen_
        return max(float(self._moments[1]) / n, 1e-12) if n else 1.0

    def predict(self, X: np.ndarray, return_std: bool = False):
        """Mean (N,), or (mean, std) with return_std=True, at X (N × n)."""
        self._check_fitted()
        X = self._check_X(X, self.n_features_in_)
        return self._predict(X, return_std)

    def _predict(self, X: np.ndarray, return_std: bool):
        Xn = np.ascontiguousarray(X / self.norm_in_)
        mean = np.empty(len(Xn))
        var = np.empty(len(Xn) if return_std else 0)
        rf = self.rf_
        _predict_batch(Xn, self._hp, self.prior_var_, return_std, self._prow, self._pcol, int(self._counts[0]),
                       rf["c"], rf["M"], rf["mean_x"], rf["beta0"], rf["n_reg"], rf["U"], rf["P"], rf["beta"],
                       rf["SSs2"], rf["sum_w"], rf["sum_e_cv2"], rf["trustworthy"], mean, var)
        mean *= self.norm_out
        if return_std:
            return mean, np.sqrt(var) * self.norm_out
        return mean

    def predict_one(self, x: np.ndarray) -> tuple[float, float]:
        """Fast (mean, std) at one input x (n,) — online use, no input checks."""
        m, v = _predict_one(np.asarray(x, dtype=float) / self.norm_in_, self._hp, self.prior_var_,
                            *self._predict_args)
        return m * self.norm_out, math.sqrt(v) * self.norm_out

    def summary(self) -> dict[str, Any]:
        """A few JSON-able numbers describing the fitted model (for model.json and logs)."""
        K = self.n_receptive_fields
        return {"receptive_fields": K, "samples": int(self.n_samples_seen_), "added": self.n_added_,
                "pruned": self.n_pruned_, "diag_only": self.diag_only_,
                "mean_projections": round(float(self.rf_["n_reg"][:K].mean()), 3) if K else 0.0,
                "trustworthy": int(self.rf_["trustworthy"][:K].sum())}

    def receptive_field_centers(self) -> np.ndarray:
        """Centres of the RFs in input units (n_rf × n)."""
        self._check_fitted()
        return self.rf_["c"][: self.n_receptive_fields] * self.norm_in_

    def distance_metrics(self) -> np.ndarray:
        """D_k = M_kᵀ M_k of each RF in normalised input units (n_rf × n × n)."""
        self._check_fitted()
        K, n = self.n_receptive_fields, self.n_features_in_
        Md = np.zeros((K, n, n))
        Md[:, self._prow, self._pcol] = self.rf_["M"][:K]
        return np.einsum("kji,kjl->kil", Md, Md)

    # --------------------------------------------------------------- state
    def get_state(self) -> dict[str, np.ndarray]:
        self._check_fitted()
        K = self.n_receptive_fields
        state = {f"rf.{name}": np.ascontiguousarray(self.rf_[name][:K]) for name in RF_NAMES}
        state["norm_in"] = self.norm_in_.copy()
        state["scalars"] = np.array([self.n_features_in_, float(self.diag_only_), self.n_samples_seen_,
                                     self.sum_y2_, self.n_added_, self.n_pruned_, self._R], dtype=float)
        return state

    def _set_state(self, arrays: dict[str, np.ndarray]) -> None:
        sc = np.asarray(arrays["scalars"], dtype=float)
        if sc.shape != (7,):
            raise ValueError(f"scalars has shape {sc.shape}, expected (7,)")
        n = int(sc[0])
        diag = bool(sc[1])
        norm_in = np.asarray(arrays["norm_in"], dtype=float)
        if n < 1 or norm_in.shape != (n,) or np.any(norm_in <= 0):
            raise ValueError("norm_in does not match the number of inputs")
        saved_diag, self.diag_only = self.diag_only, diag
        saved_norm, self.norm_in = self.norm_in, norm_in
        self._setup(n, None)
        self.diag_only, self.norm_in = saved_diag, saved_norm
        if int(sc[6]) != self._R:
            raise ValueError(f"state has {int(sc[6])} projections per RF, hyper-parameters give {self._R}")
        K = len(np.asarray(arrays["rf.c"]))
        if K > int(self.max_rfs):
            raise ValueError(f"{K} receptive fields exceed max_rfs={self.max_rfs}")
        self._allocate(max(K, 1))
        for name, kind, dt in RF_FIELDS:
            a = np.asarray(arrays[f"rf.{name}"])
            if a.shape != self._shape(kind, K):
                raise ValueError(f"rf.{name} has shape {a.shape}, expected {self._shape(kind, K)}")
            if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
                raise ValueError(f"rf.{name} holds non-finite values")
            self.rf_[name][:K] = a.astype(dt)
        if np.any(self.rf_["n_reg"][:K] < 1) or np.any(self.rf_["n_reg"][:K] > self._R):
            raise ValueError("rf.n_reg out of range")
        self._counts[:] = [K, int(sc[4]), int(sc[5])]
        self._moments[:] = [sc[2], sc[3]]


class LWPRStack:
    """LWPR models of equal shapes (one group of a ModelSet: as many inputs, the same metric packing
    and projections), stacked so that one kernel call updates or predicts all of them.

    Their state arrays are stacked along a new first axis and each model's arrays become views [g]
    of the stacked ones (LWPR._bind): the models stay ordinary LWPRs (saved, copied, learned and
    predicted one by one as before, to the bit), and the online path pays numba's dispatch and the
    Python work once per group, not once per model. A model that reallocates on its own (its own
    partial_fit growing it, fit, a loaded state) leaves the stack: `intact` turns False and the
    owner builds a new one. In memory only: model files hold each model's own get_state().
    """

    def __init__(self, models: list[LWPR], input_index: list[np.ndarray]) -> None:
        if not all(m.is_fitted for m in models):
            raise LearnerError("LWPRStack needs fitted models")
        n, n_packed, R = models[0].n_features_in_, len(models[0]._prow), models[0]._R
        if any((m.n_features_in_, len(m._prow), m._R) != (n, n_packed, R) for m in models):
            raise LearnerError("LWPRStack needs models of equal shapes")
        self.models = tuple(models)
        self.input_index = np.stack(input_index)
        self.norm_in = np.stack([m.norm_in_ for m in models])
        self.norm_out = np.array([float(m.norm_out) for m in models])
        self.prior_fixed = np.array([m.prior_var_ if m.prior_std is not None else np.nan for m in models])
        self.hp = np.stack([m._hp for m in models])
        self.max_rfs = int(self.hp[:, HP_MAX_RFS].max())
        self._fixed = (self.hp, np.stack([m._initM for m in models]), np.stack([m._initAlpha for m in models]),
                       np.stack([m._prow for m in models]), np.stack([m._pcol for m in models]))
        self._scratch = (np.zeros(n), np.zeros(n), *workspace(n, n_packed, R))
        self._all = np.ones(len(models), dtype=bool)
        self._stack(max(m.rf_["c"].shape[0] for m in models))

    def _stack(self, K: int) -> None:
        """(Re)allocate the stacked arrays with room for K fields per model and bind the models to them."""
        G = len(self.models)
        counts = np.stack([m._counts for m in self.models])
        moments = np.stack([m._moments for m in self.models])
        rf = {}
        for name, kind, dt in RF_FIELDS:
            a = np.zeros((G, *self.models[0]._shape(kind, K)), dtype=dt)
            for g, m in enumerate(self.models):
                used = int(counts[g, 0])
                a[g, :used] = m.rf_[name][:used]
            rf[name] = a
        self._bound = []
        for g, m in enumerate(self.models):
            m._bind({name: a[g] for name, a in rf.items()}, counts[g], moments[g])
            self._bound.append(m.rf_)
        fields = tuple(rf[name] for name in RF_NAMES)
        hp, _, _, prow, pcol = self._fixed
        self._update_args = (*self._fixed, counts, moments, *self._scratch, *fields)
        self._predict_args = (self.prior_fixed, self.norm_out, hp, prow, pcol, counts, moments, *self._scratch[:3],
                              *(rf[k] for k in ("c", "M", "mean_x", "beta0", "n_reg", "U", "P", "beta", "SSs2",
                                                "sum_w", "sum_e_cv2", "trustworthy")))

    @property
    def intact(self) -> bool:
        """Whether every model still works in the stacked arrays."""
        return all(m.rf_ is rf for m, rf in zip(self.models, self._bound))

    def update(self, xs: np.ndarray, y: np.ndarray, learn: np.ndarray) -> None:
        """LWPR.update of each model g with learn[g]: its columns input_index[g] of xs, target y[g]."""
        X = xs[self.input_index] / self.norm_in
        Y = y / self.norm_out
        while (full := _update_stack(X, Y, learn, *self._update_args)) >= 0:
            self._stack(min(2 * self.models[full].rf_["c"].shape[0], self.max_rfs))

    def predict(self, xs: np.ndarray, active: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(mean, std) of each model (LWPR.predict_one at its columns of xs); with `active`, only those
        models (the others' entries are 0)."""
        G = len(self.models)
        mean = np.zeros(G)
        std = np.zeros(G)
        _predict_stack(xs[self.input_index] / self.norm_in, self._all if active is None else active,
                       *self._predict_args, mean, std)
        return mean, std
