"""Signal conditioning of the paper (§III-C): a linear-phase FIR low-pass for q, q̇, τ, u,
and the same low-pass convolved with a central difference for q̈.

The filters are specified in hertz and seconds and designed for the log's measured rate
(ciml_learning.core.stamps.measure_rate), never for an assumed one: a window of WINDOW_S
(0.124 s, the paper's ~0.12 s) holds n = taps_for_rate(fs) samples (odd), e.g. 31 at
250 Hz, 55 at 448 Hz, 61 at 500 Hz, 125 at 1 kHz. Both filters are linear-phase with the
same delay, (n − 1)/2 samples (≈ 60 ms at any rate), so every filtered signal refers to
the same instant. Offline the filters are applied centred (zero phase) over a whole log;
online the same taps run causally and the output belongs to the instant `delay` samples
ago — identical numbers.

Design (scipy.signal.firls, least squares): passband 0–5 Hz (gain within 1 %),
stopband from 20 Hz (≥ 20 dB attenuation), −2 dB at 10 Hz: the paper's 10 Hz low-pass
with a flat passband for gait harmonics. The derivative filter is the (n − 2)-tap
version of the low-pass convolved with [1, 0, −1]/(2Δt): n taps, antisymmetric.
"""
from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass

import numpy as np
import scipy.ndimage
import scipy.signal

WINDOW_S = 0.124
"""Filter window [s]: the paper's ~0.12 s (31 taps at 250 Hz)."""
N_TAPS = 31
"""Taps at 250 Hz (taps_for_rate(250.0)); other rates get their own count."""
PASSBAND_HZ = 5.0
STOPBAND_HZ = 20.0
PASSBAND_WEIGHT = 20.0


def taps_for_rate(fs: float, window_s: float = WINDOW_S) -> int:
    """Odd tap count whose window (n − 1)/fs + 1/fs spans `window_s` seconds at `fs` Hz."""
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"sample rate must be a positive number of hertz, got {fs}")
    half = int(round((window_s * fs - 1.0) / 2.0))
    return 2 * max(half, 2) + 1


def lowpass_taps(fs: float, n_taps: int | None = None, passband: float = PASSBAND_HZ,
                 stopband: float = STOPBAND_HZ) -> np.ndarray:
    """Linear-phase low-pass FIR taps (odd length, taps_for_rate(fs) by default), unit DC gain."""
    if n_taps is None:
        n_taps = taps_for_rate(fs)
    if stopband >= fs / 2:
        raise ValueError(f"sample rate {fs:.1f} Hz is too low for a {stopband:g} Hz stopband")
    if n_taps % 2 == 0:
        raise ValueError("n_taps must be odd for a linear-phase filter with an integer delay")
    taps = scipy.signal.firls(n_taps, [0, passband, stopband, fs / 2], [1, 1, 0, 0], fs=fs,
                              weight=[PASSBAND_WEIGHT, 1])
    return taps / taps.sum()


def derivative_taps(fs: float, n_taps: int | None = None) -> np.ndarray:
    """Low-pass differentiator: (n_taps − 2)-tap low-pass ⊛ central difference, [1/s]."""
    if n_taps is None:
        n_taps = taps_for_rate(fs)
    return np.convolve(lowpass_taps(fs, n_taps - 2), [1.0, 0.0, -1.0]) * fs / 2.0


def delay_samples(n_taps: int = N_TAPS) -> int:
    """Delay of an n_taps linear-phase filter [samples] (15 for the 250 Hz default)."""
    return (n_taps - 1) // 2


def delay_for_rate(fs: float) -> int:
    """Delay of the filters designed for `fs` [samples] (≈ WINDOW_S / 2 in seconds)."""
    return delay_samples(taps_for_rate(fs))


def filter_offline(x: np.ndarray, taps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Zero-phase filtering along axis 0; returns (y, valid) with the edges marked invalid.

    y[n] = Σ_k taps[k] x[n + d − k], d = delay; the first and last d samples lack a
    full window and are invalid (their values are still finite, from edge padding).
    """
    x = np.asarray(x, dtype=float)
    d = (len(taps) - 1) // 2
    y = scipy.ndimage.convolve1d(x, taps, axis=0, mode="nearest")
    valid = np.ones(len(x), dtype=bool)
    valid[:d] = False
    valid[len(x) - d:] = False
    return y, valid


class OnlineFilter:
    """Causal streaming version of filter_offline for a vector signal.

    push(x) returns the filtered value for the instant `delay` samples before x (or None
    during warm-up); it equals filter_offline's output at that instant.
    """

    def __init__(self, taps: np.ndarray) -> None:
        self.taps = np.asarray(taps, dtype=float)
        self.delay = (len(self.taps) - 1) // 2
        self._window: deque[np.ndarray] = deque(maxlen=len(self.taps))

    def reset(self) -> None:
        self._window.clear()

    def push(self, x: np.ndarray) -> np.ndarray | None:
        self._window.append(np.asarray(x, dtype=float))
        if len(self._window) < len(self.taps):
            return None
        # window[-1] is newest: y = Σ taps[k] x[n − k]
        return np.tensordot(self.taps[::-1], np.asarray(self._window), axes=(0, 0))


def contact_change_mask(contacts: np.ndarray, half_window: int = delay_samples()) -> np.ndarray:
    """True where no contact flag changes within ±half_window samples (usable for training).

    Impacts make the velocity discontinuous, so filtered accelerations near a touchdown
    or lift-off are wrong (paper §III-C). This masks the rigid-body error only: the actuation
    error Γ = τ − u (eq. 14) is made of torques, which an impact does not make jump, and a
    trot's largest torque rates are near its contact changes — left out, the actuation models
    never see the τ̇ a reference asks for there (`effort_valid`: valid but for this mask).
    """
    contacts = np.asarray(contacts, dtype=bool)
    n = len(contacts)
    change = np.flatnonzero(np.any(contacts[1:] != contacts[:-1], axis=1)) + 1 if n > 1 else np.zeros(0, int)
    # the change happens between k−1 and k; both sides within half a window are affected:
    # [k − half_window, k + half_window) for every change k, as a running count of open intervals
    edges = np.zeros(n + 1, dtype=np.int64)
    np.add.at(edges, np.maximum(change - half_window, 0), 1)
    np.add.at(edges, np.minimum(change + half_window, n), -1)
    return np.cumsum(edges[:n]) <= 0


def quaternion_continuity(quat_xyzw: np.ndarray) -> np.ndarray:
    """Flip quaternion signs so consecutive samples are in the same hemisphere (for filtering)."""
    q = np.array(quat_xyzw, dtype=float)
    if len(q) < 2:
        return q
    # sample k is flipped iff its dot with sample k−1 *as output* is negative: the output sign is
    # the parity of the raw negative dots since the last raw dot that is 0 or NaN (which restarts it)
    dots = np.einsum("ij,ij->i", q[1:], q[:-1])
    negative = np.concatenate([[0], np.cumsum(dots < 0)])
    restart = np.concatenate([[0], np.where((dots < 0) | (dots > 0), 0, np.arange(1, len(q)))])
    flips = negative - negative[np.maximum.accumulate(restart)]
    q[flips % 2 == 1] *= -1.0
    return q


MAX_FILLED_SAMPLES = 8
"""Longest run of missing samples bridged by interpolation instead of a restart (32 ms at
250 Hz, a quarter of the 31-sample window).

A sensor topic loses messages under load, often a few in a row when the reading process
waited for the CPU; restarting the filter would interrupt /filtered_state for a whole
window (31 samples) each time: on the 2-core machine's live graph, restarts after 3–8
lost samples cost more output than all the lost samples together (results/LIVE_GRAPH.md,
third session). Short gaps
on the regular grid are filled by linear interpolation (quaternions: normalised lerp,
contacts held) before filtering; the filled instants themselves are never output, and
outputs whose window holds a filled instant are marked invalid for training (their
values are approximate). Offline and online filters bridge exactly the same gaps, so
they still agree sample for sample.
"""


def missing_samples(dt: float, fs: float, max_gap_factor: float) -> int:
    """Number of samples to fill for a step dt: 0 if regular, −1 if too long (restart)."""
    if dt <= max_gap_factor / fs:
        return 0
    k = int(round(dt * fs)) - 1
    if 1 <= k <= MAX_FILLED_SAMPLES and abs(dt * fs - (k + 1)) < 0.25:
        return k
    return -1


def _interpolate_row(a: np.ndarray, b: np.ndarray, w: float, quat: slice | None) -> np.ndarray:
    x = (1.0 - w) * a + w * b
    if quat is not None:
        qb = b[quat] if np.dot(a[quat], b[quat]) >= 0 else -b[quat]
        qx = (1.0 - w) * a[quat] + w * qb
        x[quat] = qx / np.linalg.norm(qx)
    return x


def fill_short_gaps(t: np.ndarray, signals: list[np.ndarray], contacts: np.ndarray, fs: float,
                    max_gap_factor: float, quat: slice | None = slice(3, 7)):
    """Insert interpolated rows into short gaps (see MAX_FILLED_SAMPLES).

    signals[0] is the configuration (its quaternion columns `quat` are interpolated on
    the sphere). Returns (t, signals, contacts, filled) with filled marking inserted rows.
    """
    n = len(t)
    inserts = []
    for k in (np.flatnonzero(np.diff(t) > max_gap_factor / fs) + 1).tolist():  # missing_samples is 0 elsewhere
        m = missing_samples(t[k] - t[k - 1], fs, max_gap_factor)
        if m > 0 and all(np.all(np.isfinite(x[k - 1])) and np.all(np.isfinite(x[k])) for x in signals):
            inserts.append((k, m))
    if not inserts:
        return t, signals, contacts, np.zeros(n, dtype=bool)
    rows_t: list[np.ndarray] = []
    rows_x: list[list[np.ndarray]] = [[] for _ in signals]
    rows_c: list[np.ndarray] = []
    filled: list[np.ndarray] = []
    prev = 0
    for k, m in inserts:
        rows_t.append(t[prev:k])
        for i, x in enumerate(signals):
            rows_x[i].append(x[prev:k])
        rows_c.append(contacts[prev:k])
        filled.append(np.zeros(k - prev, dtype=bool))
        for j in range(1, m + 1):
            w = j / (m + 1)
            rows_t.append(np.array([(1 - w) * t[k - 1] + w * t[k]]))
            for i, x in enumerate(signals):
                rows_x[i].append(_interpolate_row(x[k - 1], x[k], w, quat if i == 0 else None)[None])
            rows_c.append(contacts[k - 1][None])
            filled.append(np.ones(1, dtype=bool))
        prev = k
    rows_t.append(t[prev:])
    for i, x in enumerate(signals):
        rows_x[i].append(x[prev:])
    rows_c.append(contacts[prev:])
    filled.append(np.zeros(n - prev, dtype=bool))
    return (np.concatenate(rows_t), [np.concatenate(r) for r in rows_x], np.concatenate(rows_c),
            np.concatenate(filled))


@dataclass
class FilteredLog:
    """A log after conditioning, in Pinocchio conventions, one row per sample.

    q (N × nq): low-passed joints and base position, low-passed normalised base quaternion;
    v, a (N × nv): low-passed velocities and their filtered derivative (base twist in the
    base frame); tau, u (N × n_j): low-passed torques; tau_dot: filtered derivative of τ;
    contacts (N × n_feet); valid: usable for training; invalid_counts: why samples were not;
    effort_valid: τ, τ̇ and u usable — valid but for the contact changes (contact_change_mask).
    """

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    tau: np.ndarray
    tau_dot: np.ndarray
    u: np.ndarray
    contacts: np.ndarray
    valid: np.ndarray
    invalid_counts: dict[str, int]
    segment: np.ndarray
    """Segment id of each sample (the log is split at time gaps and non-finite samples)."""
    rate_hz: float
    """Rate the filters were designed for [Hz] (the log's measured rate)."""
    segment_rate_hz: np.ndarray | None = None
    """Per segment id, its log's rate [Hz] (logs of different rates concatenated), else None."""
    effort_valid: np.ndarray | None = None
    """(N,) the rows Γ = τ − u learns from (contact_change_mask); None: `valid`."""

    def __len__(self) -> int:
        return len(self.t)


def filter_state_log(
    t: np.ndarray,
    q: np.ndarray,
    v: np.ndarray,
    tau: np.ndarray,
    u: np.ndarray,
    contacts: np.ndarray,
    fs: float | None = None,
    max_gap_factor: float = 1.5,
) -> FilteredLog:
    """Offline (zero-phase) conditioning of a whole log (paper §III-C).

    fs [Hz]: the rate the filters are designed for; None measures it from t (median
    period, ciml_learning.core.stamps.measure_rate) — never an assumed rate.

    The log is split into segments at time gaps > max_gap_factor/fs (and at non-finite
    samples); each segment is filtered separately and its edges are invalid. Samples near
    contact changes are invalid for training. Nothing non-finite reaches the output:
    rows that were non-finite are marked invalid and hold finite placeholder values.
    """
    t = np.asarray(t, dtype=float)
    n = len(t)
    if n == 0:
        raise ValueError("empty log")
    if np.any(np.diff(t) <= 0):
        raise ValueError("time stamps must increase strictly")
    if fs is None:
        from ciml_learning.core.stamps import measure_rate

        fs = measure_rate(t).rate_hz
    raw = [np.asarray(x, dtype=float) for x in (q, v, tau, u)]
    t_in = t
    t, raw, contacts, filled = fill_short_gaps(t, raw, np.asarray(contacts, dtype=bool), fs, max_gap_factor)
    n = len(t)
    finite = np.all(np.isfinite(np.hstack([r.reshape(n, -1) for r in raw])), axis=1) & np.isfinite(t)
    gap = np.zeros(n, dtype=bool)
    gap[1:] = np.diff(t) > max_gap_factor / fs
    starts = np.flatnonzero(gap | np.r_[True, ~finite[:-1]] | ~finite)
    lp = lowpass_taps(fs)
    dp = derivative_taps(fs)
    out_q, out_v, out_a = np.zeros_like(raw[0]), np.zeros_like(raw[1]), np.zeros_like(raw[1])
    out_tau, out_tau_dot, out_u = np.zeros_like(raw[2]), np.zeros_like(raw[2]), np.zeros_like(raw[3])
    valid = finite.copy()
    counts = {"non_finite": int((~finite).sum()), "time_gap_segments": int(gap.sum()), "filter_edges": 0,
              "contact_change": 0}
    segment = np.zeros(n, dtype=int)
    bounds = list(starts) + [n]
    for s_i, (s, e) in enumerate(zip(bounds[:-1], bounds[1:])):
        segment[s:e] = s_i
        if e <= s:
            continue
        if not finite[s]:
            out_q[s:e] = np.nan_to_num(raw[0][s:e])
            out_q[s:e, 3:7] = [0, 0, 0, 1]
            continue
        seg = slice(s, e)
        qs = raw[0][seg].copy()
        qs[:, 3:7] = quaternion_continuity(qs[:, 3:7])
        fq, ok = filter_offline(qs, lp)
        fq[:, 3:7] /= np.linalg.norm(fq[:, 3:7], axis=1, keepdims=True)
        out_q[seg] = fq
        out_v[seg], _ = filter_offline(raw[1][seg], lp)
        out_a[seg], _ = filter_offline(raw[1][seg], dp)
        out_tau[seg], _ = filter_offline(raw[2][seg], lp)
        out_tau_dot[seg], _ = filter_offline(raw[2][seg], dp)
        out_u[seg], _ = filter_offline(raw[3][seg], lp)
        counts["filter_edges"] += int((~ok & valid[seg]).sum())
        valid[seg] &= ok
    d = delay_samples(len(lp))
    near_fill = np.convolve(filled.astype(float), np.ones(2 * d + 1), mode="same") > 0
    effort_valid = valid & ~near_fill
    cmask = contact_change_mask(contacts, half_window=d)
    counts["contact_change"] = int((~cmask & valid & ~filled).sum())
    valid &= cmask
    counts["bridged_gap_window"] = int((near_fill & valid & ~filled).sum())
    valid &= ~near_fill
    keep = ~filled  # filled instants are never output
    counts["filled_samples"] = int(filled.sum())
    return FilteredLog(t=t_in, q=out_q[keep], v=out_v[keep], a=out_a[keep], tau=out_tau[keep],
                       tau_dot=out_tau_dot[keep], u=out_u[keep], contacts=contacts[keep], valid=valid[keep],
                       invalid_counts=counts, segment=segment[keep], rate_hz=float(fs),
                       effort_valid=effort_valid[keep])


@dataclass
class FilteredSample:
    """One online-filtered sample, aligned to time t (= newest input time − delay)."""

    t: float
    q: np.ndarray
    v: np.ndarray
    a: np.ndarray
    tau: np.ndarray
    tau_dot: np.ndarray
    u: np.ndarray
    contacts: np.ndarray
    valid: bool
    effort_valid: bool
    """τ, τ̇, u usable: valid but for a contact change (contact_change_mask)."""


class OnlineStateFilter:
    """Causal counterpart of filter_state_log for live data (the state_filter node).

    push() takes one raw sample and returns the filtered samples that became ready: the
    one of `delay` samples ago, or none while warming up (or several after a bridged
    gap). Its numbers equal filter_state_log's at interior samples: short gaps are
    bridged the same way (fill_short_gaps); a longer gap, a non-increasing stamp or a
    non-finite sample restarts the warm-up.
    """

    def __init__(self, fs: float, max_gap_factor: float = 1.5) -> None:
        """fs [Hz]: the rate of the incoming samples (the filters are designed for it)."""
        self.fs = fs
        self.max_gap_factor = max_gap_factor
        self._lp = lowpass_taps(fs)
        self._dp = derivative_taps(fs)
        self.delay = delay_samples(len(self._lp))
        self.filled = 0  # raw samples interpolated into short gaps (never output)
        self.restarts = 0  # warm-ups restarted by a long gap or a non-increasing stamp
        # outputs that are valid, and why the others are not (filter_state_log's invalid_counts names)
        self.counts: Counter[str] = Counter()
        self.reset()

    def reset(self) -> None:
        self._low = OnlineFilter(self._lp)
        self._der = OnlineFilter(self._dp)
        self._history: deque = deque(maxlen=len(self._lp))  # (t, contacts, filled)
        self._last: tuple | None = None  # (t, q, v, tau, u, contacts) of the newest raw sample

    def push(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray, u: np.ndarray,
             contacts: np.ndarray) -> list[FilteredSample]:
        raw = np.concatenate([q, v, tau, u])
        if not np.all(np.isfinite(raw)) or not np.isfinite(t):
            self.reset()
            raise ValueError("non-finite sample")
        q = np.array(q, dtype=float)
        contacts = np.asarray(contacts, dtype=bool).copy()
        out: list[FilteredSample] = []
        if self._last is not None:
            missing = missing_samples(t - self._last[0], self.fs, self.max_gap_factor)
            if t <= self._last[0] or missing < 0:
                self.restarts += 1
                self.reset()
            elif missing > 0:
                self.filled += missing
                t0, q0, v0, tau0, u0, c0 = self._last
                new = (q, np.asarray(v, float), np.asarray(tau, float), np.asarray(u, float))
                for j in range(1, missing + 1):
                    w = j / (missing + 1)
                    qi, vi, taui, ui = (_interpolate_row(a, b, w, slice(3, 7) if i == 0 else None)
                                        for i, (a, b) in enumerate(zip((q0, v0, tau0, u0), new)))
                    self._push_one((1 - w) * t0 + w * t, qi, vi, taui, ui, c0, filled=True, out=out)
        self._push_one(t, q, np.asarray(v, float), np.asarray(tau, float), np.asarray(u, float), contacts,
                       filled=False, out=out)
        return out

    def _push_one(self, t: float, q: np.ndarray, v: np.ndarray, tau: np.ndarray, u: np.ndarray,
                  contacts: np.ndarray, filled: bool, out: list[FilteredSample]) -> None:
        if self._last is not None and np.dot(q[3:7], self._last[1][3:7]) < 0:
            q = q.copy()
            q[3:7] = -q[3:7]  # hemisphere continuity, as quaternion_continuity
        self._last = (t, q, v, tau, u, contacts)
        nq, nv, nj = len(q), len(v), len(tau)
        low = self._low.push(np.concatenate([q, v, tau, u]))
        der = self._der.push(np.concatenate([v, tau]))
        self._history.append((t, contacts, filled))
        if low is None or der is None:  # both filters have the same delay: warm together
            return
        t_out, c_out, filled_out = self._history[self.delay]
        if filled_out:
            return  # filled instants are never output
        flags = np.array([c for _, c, _ in self._history])
        # no contact change and no interpolated input within ±delay
        changed = not bool(np.all(flags == flags[0]))
        near_fill = any(f for _, _, f in self._history)
        valid = not changed and not near_fill
        self.counts["effort_valid"] += not near_fill
        self.counts["valid" if valid else "contact_change" if changed else "bridged_gap_window"] += 1
        qf = low[:nq].copy()
        qf[3:7] /= np.linalg.norm(qf[3:7])
        out.append(FilteredSample(t=t_out, q=qf, v=low[nq:nq + nv], a=der[:nv], tau=low[nq + nv:nq + nv + nj],
                                  tau_dot=der[nv:], u=low[nq + nv + nj:], contacts=c_out, valid=valid,
                                  effort_valid=not near_fill))
