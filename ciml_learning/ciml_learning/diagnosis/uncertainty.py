"""Parameter uncertainty that covers the truth as often as it claims (docs/DIAGNOSIS.md).

A parameter's reported standard deviation combines, in quadrature:

1. sampling: a block bootstrap over time of the identification data (block_bootstrap). The
   residual of low-passed signals is strongly autocorrelated (the filter window alone spans
   ~0.1 s, a misfit of the model follows the motion for longer), so blocks must be longer than
   the residual's correlation: block_length = BLOCK_FACTOR × the integrated autocorrelation time
   of the residual left after the selected effects (at least MIN_BLOCK_SECONDS). The residual is
   the one *after* the selected effects, so what they miss (misspecification) is resampled with
   its own correlation; the baseline and every selected effect are refitted in each draw, so the
   baseline's correlation with an effect widens the effect's interval;
2. reproduction: the same model refitted on the held-out data (other motions): a parameter that
   depends on the motion it is fitted on is not known better than the two estimates agree
   (|θ_id − θ_ho| / √2, the standard deviation of one estimate if both were independent draws);
3. conversion: the actuator lag's time constant is read from the logs' command sampling
   (identification.lag_time_constant); a torque reading is timed only to within its sample
   period, and a timing offset reads as a lag: sample period / √12;
4. misspecification: what the selected model leaves above the noise floor (a simulator's contact
   softness, an effect outside the catalogue, the linearisations) biases the parameters, the same
   on every subset of the data, so neither 1 nor 2 sees it. A least-squares coefficient moves by at
   most ‖r‖/‖x‖ when a residual r is added to its data (Cauchy–Schwarz); relative to the effect's
   own prediction x θ that is √(r²/s²) (identification.misspecification_bounds). That worst case
   (all of r along the effect) is taken as MISSPECIFICATION_SCALE⁻¹ standard deviations;
5. resolution: RESOLUTION of the effect's size (|θ − no effect|). On noise-free logs of an exact
   effect 1–4 vanish (gap-bench case 5: a torque offset of 3 Nm came out 2.999999997 ± 2.4e-14 Nm,
   an interval that missed the truth by 3e-9): below that resolution the estimate differs by
   rounding in the filters and solvers, not by information in the data.

The unit test checks coverage on synthetic regressions with AR(1) noise (block_bootstrap,
block_length: the functions the diagnosis uses).
"""
from __future__ import annotations

from collections.abc import Callable

import numpy as np

BLOCK_FACTOR = 3.0
"""Block length in units of the residual's integrated autocorrelation time."""
MIN_BLOCK_SECONDS = 1.0
"""Shortest block [s] (the filter window and a gait cycle fit inside)."""
MIN_BLOCKS = 20
"""Blocks are shortened so that the data hold at least this many (a bootstrap needs several)."""
N_BOOT = 100
MISSPECIFICATION_SCALE = 0.5
"""The misspecification bound (worst case) counts as 1/0.5 = 2 standard deviations."""
RESOLUTION = 1e-6
"""The smallest standard deviation of a parameter, relative to the effect's size (component 5)."""
Z95, Z68 = 1.959964, 0.994458
"""Normal quantiles of the reported two-sided 95 % and 68 % intervals (value ± z·std)."""


def integrated_autocorrelation_time(x: np.ndarray) -> float:
    """τ_int = 1 + 2 Σ_k ρ_k [samples] of a series, summed while ρ_k stays positive (initial positive
    sequence): the number of samples that carry the information of one independent sample."""
    x = np.asarray(x, float)
    x = x - x.mean()
    n = len(x)
    if n < 4 or not np.any(x):
        return 1.0
    f = np.fft.rfft(x, 2 * n)
    acf = np.fft.irfft(f * np.conj(f))[:n]
    rho = acf / acf[0]
    neg = np.flatnonzero(rho[1:] <= 0)
    stop = int(neg[0]) + 1 if len(neg) else n
    return float(max(1.0, 1.0 + 2.0 * rho[1:stop].sum()))


def integrated_autocorrelation_time_max(residuals: list[np.ndarray]) -> float:
    """The largest integrated_autocorrelation_time of several series [samples]."""
    return max([integrated_autocorrelation_time(r) for r in residuals if len(r) >= 4] or [1.0])


def block_length(residuals: list[np.ndarray], fs: float, n_samples: int) -> int:
    """Bootstrap *sub-block* length [samples] (block_bootstrap: a block is SPAN of them): a block is
    BLOCK_FACTOR × the largest integrated autocorrelation time of the given residual series, at
    least MIN_BLOCK_SECONDS, at most n_samples / MIN_BLOCKS."""
    tau = integrated_autocorrelation_time_max(residuals)
    block = int(np.ceil(max(BLOCK_FACTOR * tau, MIN_BLOCK_SECONDS * fs)))
    block = int(max(1, min(block, n_samples // MIN_BLOCKS if n_samples >= MIN_BLOCKS else n_samples)))
    return max(1, int(np.ceil(block / SPAN)))


SPAN = 4
"""Sub-blocks per block: blocks start every 1/SPAN of a block (a moving-block bootstrap, whose
overlapping blocks lose less of the correlation at block edges than disjoint ones)."""


def block_bootstrap(Gb: np.ndarray, cb: np.ndarray, fit: Callable[[np.ndarray, np.ndarray], np.ndarray],
                    n_boot: int = N_BOOT, seed: int = 0, span: int = SPAN) -> np.ndarray:
    """Draws (n_boot × p) of fit(G, c) on a moving-block bootstrap: Gb (n_sub × f × f), cb (n_sub × f)
    are the sufficient statistics (Xᵀ W X, Xᵀ W y) of consecutive sub-blocks; a block is `span`
    consecutive sub-blocks, ⌈n_sub / span⌉ blocks are drawn with replacement from all starts."""
    rng = np.random.default_rng(seed)
    n_sub = len(Gb)
    span = max(1, min(span, n_sub))
    Gc = np.concatenate([np.zeros((1,) + Gb.shape[1:]), np.cumsum(Gb, axis=0)])
    cc = np.concatenate([np.zeros((1,) + cb.shape[1:]), np.cumsum(cb, axis=0)])
    Gblk, cblk = Gc[span:] - Gc[:-span], cc[span:] - cc[:-span]  # every block start
    n_draw = int(np.ceil(n_sub / span))
    out = []
    for _ in range(n_boot):
        pick = rng.integers(0, len(Gblk), n_draw)
        scale = n_sub / (n_draw * span)  # the same amount of data as the original
        out.append(np.asarray(fit(Gblk[pick].sum(axis=0) * scale, cblk[pick].sum(axis=0) * scale), float))
    return np.asarray(out)


def bootstrap_std(draws: np.ndarray, n_sub: int, span: int = SPAN) -> np.ndarray:
    """Standard deviation of bootstrap draws for normal-quantile intervals: with the n/(n − 1)
    small-sample correction of the blocks, and scaled by t_{0.975, n−1} / z_{0.975} — a spread
    estimated from n blocks is itself uncertain, so value ± 1.96 std is the Student-t interval."""
    from scipy.stats import norm, t

    if len(draws) < 2:
        return np.zeros(draws.shape[1:])
    n_blocks = int(np.ceil(n_sub / max(1, min(span, n_sub))))
    corr = np.sqrt(n_blocks / max(n_blocks - 1, 1))
    dof = max(n_blocks - 1, 1)
    return np.std(draws, axis=0, ddof=1) * corr * float(t.ppf(0.975, dof) / norm.ppf(0.975))


def combine(*parts: np.ndarray) -> np.ndarray:
    """Independent error sources in quadrature."""
    return np.sqrt(np.sum([np.asarray(p, float) ** 2 for p in parts], axis=0))
