"""The true sample rate of a log and what is wrong with its stamps.

A robot's joint states come at its own rate (200 Hz–1 kHz) and rarely on a perfect grid:
messages are dropped (gaps), delivered in bunches (bursts), stamped twice or not at all.
The rate is the median period of the stamps — robust to all of these — and the filters
are designed for it (ciml_learning.core.filters.taps_for_rate). Nothing here assumes a rate.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

GAP_FACTOR = 1.5
"""A step longer than GAP_FACTOR median periods is a gap (a lost sample or more)."""
BURST_FACTOR = 0.5
"""A step shorter than BURST_FACTOR median periods is a burst (samples delivered together)."""
IRREGULAR_TOLERANCE = 0.1
"""A step more than ±10 % off the median period counts as irregular."""


@dataclass(frozen=True)
class StampReport:
    """Stamp statistics of one topic; times in seconds, rate in hertz."""

    count: int
    rate_hz: float
    median_period_s: float
    zero_stamps: int
    non_monotonic: int
    duplicates: int
    gaps: int
    longest_gap_s: float
    bursts: int
    irregular_fraction: float

    def problems(self) -> list[str]:
        """Human-readable list of what is wrong (empty when the stamps are clean)."""
        out = []
        if self.zero_stamps:
            out.append(f"{self.zero_stamps} zero stamps")
        if self.non_monotonic:
            out.append(f"{self.non_monotonic} stamps going backwards")
        if self.duplicates:
            out.append(f"{self.duplicates} duplicated stamps")
        if self.gaps:
            out.append(f"{self.gaps} gaps (longest {self.longest_gap_s * 1e3:.1f} ms)")
        if self.bursts:
            out.append(f"{self.bursts} bursts (steps < {BURST_FACTOR:g} period)")
        if self.irregular_fraction > 0.05:
            out.append(f"{self.irregular_fraction:.0%} of steps more than {IRREGULAR_TOLERANCE:.0%} off the period")
        return out

    def as_dict(self) -> dict:
        d = asdict(self)
        d["problems"] = self.problems()
        return d


def count_zero_stamps(t: np.ndarray) -> int:
    """Stamps equal to zero, except a single first one (a simulation clock starts at 0)."""
    t = np.asarray(t, dtype=float)
    zero = int(np.sum(t == 0.0))
    return zero - 1 if zero == 1 and len(t) and t[0] == 0.0 else zero


def measure_rate(t: np.ndarray) -> StampReport:
    """Rate and stamp problems of a series of stamps t [s] in arrival order.

    The rate is 1 / median of the positive steps; with fewer than two distinct stamps
    it is NaN (callers reject such a log).
    """
    t = np.asarray(t, dtype=float)
    zero = count_zero_stamps(t)
    dt = np.diff(t)
    pos = dt[dt > 0]
    # stamps are integer nanoseconds: round the period to them (250 Hz is 250.0, not 249.99…)
    period = float(np.round(np.median(pos) * 1e9) * 1e-9) if len(pos) else float("nan")
    rate = 1.0 / period if len(pos) else float("nan")
    if len(pos):
        gaps = dt > GAP_FACTOR * period
        bursts = (dt > 0) & (dt < BURST_FACTOR * period)
        irregular = float(np.mean(np.abs(dt - period) > IRREGULAR_TOLERANCE * period))
        longest = float(dt[gaps].max()) if gaps.any() else 0.0
    else:
        gaps = bursts = np.zeros(len(dt), dtype=bool)
        irregular, longest = 0.0, 0.0
    return StampReport(count=len(t), rate_hz=rate, median_period_s=period, zero_stamps=zero,
                       non_monotonic=int(np.sum(dt < 0)), duplicates=int(np.sum(dt == 0)),
                       gaps=int(gaps.sum()), longest_gap_s=longest, bursts=int(bursts.sum()),
                       irregular_fraction=irregular)


def resample(t: np.ndarray, x: np.ndarray, rate_hz: float, start: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of x (N × …) onto a uniform grid of `rate_hz` inside [t0, t_end].

    The grid starts at `start` (default: the first stamp t0; a later start shifts its phase).
    For comparing a log with its explicit resampling; the pipeline itself filters at the
    log's own rate instead of resampling.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    t0 = t[0] if start is None else float(start)
    if not t[0] <= t0 <= t[-1]:
        raise ValueError(f"resample: start {t0} outside the stamps [{t[0]}, {t[-1]}]")
    grid = t0 + np.arange(int(np.floor((t[-1] - t0) * rate_hz + 1e-9)) + 1) / rate_hz
    flat = x.reshape(len(t), -1)
    out = np.stack([np.interp(grid, t, flat[:, k]) for k in range(flat.shape[1])], axis=1)
    return grid, out.reshape((len(grid),) + x.shape[1:])
