"""The paper's FIR filters: passband accuracy, stopband attenuation, delay, online = offline."""
import numpy as np
import pytest
import scipy.signal

from ciml_learning.core.filters import (
    MAX_FILLED_SAMPLES,
    OnlineFilter,
    contact_change_mask,
    delay_samples,
    derivative_taps,
    filter_offline,
    filter_state_log,
    lowpass_taps,
    quaternion_continuity,
)

FS = 250.0


@pytest.mark.parametrize("freq", [0.5, 1.0, 2.0, 3.0])
def test_derivative_of_a_slow_sinusoid_within_one_percent_and_zero_phase(freq):
    t = np.arange(3000) / FS
    x = np.sin(2 * np.pi * freq * t + 0.3)
    y, valid = filter_offline(x, derivative_taps(FS))
    true = 2 * np.pi * freq * np.cos(2 * np.pi * freq * t + 0.3)
    assert np.max(np.abs(y[valid] - true[valid])) <= 0.01 * 2 * np.pi * freq


def test_lowpass_passes_gait_band_and_attenuates_above_20_hz():
    taps = lowpass_taps(FS)
    assert len(taps) == 31 and len(derivative_taps(FS)) == 31
    f = np.array([0.5, 1, 2, 4])
    _, h = scipy.signal.freqz(taps, worN=f, fs=FS)
    assert np.all(np.abs(np.abs(h) - 1) < 0.01)
    f_stop = np.linspace(20, FS / 2, 200)
    _, h = scipy.signal.freqz(taps, worN=f_stop, fs=FS)
    assert np.max(20 * np.log10(np.abs(h))) <= -20.0
    _, hd = scipy.signal.freqz(derivative_taps(FS), worN=f_stop, fs=FS)
    assert np.max(20 * np.log10(np.abs(hd) / (2 * np.pi * f_stop))) <= -20.0


def test_linear_phase_delay_is_half_the_window():
    assert delay_samples() == 15
    taps = lowpass_taps(FS)
    np.testing.assert_allclose(taps, taps[::-1])  # symmetric ⇒ linear phase, delay (N−1)/2
    d = derivative_taps(FS)
    np.testing.assert_allclose(d, -d[::-1])


def test_online_equals_offline_after_the_delay():
    rng = np.random.default_rng(0)
    x = np.cumsum(rng.normal(size=(400, 5)), axis=0)
    for taps in (lowpass_taps(FS), derivative_taps(FS)):
        y, valid = filter_offline(x, taps)
        f = OnlineFilter(taps)
        outs = [f.push(row) for row in x]
        assert all(o is None for o in outs[:30])
        for k in range(30, 400):
            np.testing.assert_allclose(outs[k], y[k - f.delay], atol=1e-9)


def test_contact_change_mask_marks_half_a_window_each_side():
    c = np.ones((100, 4), dtype=bool)
    c[50:, 1] = False
    ok = contact_change_mask(c, half_window=15)
    assert not ok[35:65].any()
    assert ok[:35].all() and ok[65:].all()


def test_vectorised_masks_and_signs_equal_their_sample_by_sample_definitions():
    """contact_change_mask and quaternion_continuity are written without a per-sample loop; here
    they meet their definitions, sample by sample: a sample is masked iff a change between k−1 and
    k lies within [k − h, k + h) of it; a quaternion is flipped iff its dot with the previous
    *output* is negative (exact zero dots included)."""
    rng = np.random.default_rng(4)
    for trial in range(200):
        n = int(rng.integers(0, 50))
        c = rng.random((n, 4)) < rng.uniform(0.02, 0.98)
        changes = [k for k in range(1, n) if (c[k] != c[k - 1]).any()]
        for h in (0, 1, 4, 15, 60):
            expected = np.array([not any(k - h <= i < k + h for k in changes) for i in range(n)], dtype=bool)
            assert np.array_equal(contact_change_mask(c, h), expected), (trial, h)
        q = rng.normal(size=(n, 4))
        if n > 4:
            q[rng.integers(0, n, 3)] = [1.0, 0, 0, 0]
            q[rng.integers(0, n)] = [0, 1.0, 0, 0]  # dots exactly 0 with its [1, 0, 0, 0] neighbours
        out = quaternion_continuity(q)
        for k in range(n):
            flip = k > 0 and float(np.dot(q[k], out[k - 1])) < 0
            assert np.array_equal(out[k], -q[k] if flip else q[k]), (trial, k)


def test_state_log_flags_non_finite_gaps_and_edges():
    n = 500
    t = np.arange(n) / FS
    t[300:] += 0.1  # a time gap
    q = np.zeros((n, 19))
    q[:, 6] = 1.0
    v = np.zeros((n, 18))
    tau = np.zeros((n, 12))
    tau[100, 3] = np.nan
    log = filter_state_log(t, q, v, tau, tau.copy(), np.ones((n, 4), bool))
    assert not log.valid[100] and log.invalid_counts["non_finite"] == 1
    assert log.invalid_counts["time_gap_segments"] == 1
    assert not log.valid[:15].any() and not log.valid[285:315].any()
    for arr in (log.q, log.v, log.a, log.tau, log.u):
        assert np.all(np.isfinite(arr))
    with pytest.raises(ValueError, match="increase"):
        filter_state_log(t[::-1], q, v, tau, tau, np.ones((n, 4), bool))


def _state_log(n: int, seed: int = 3):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / FS
    q = np.zeros((n, 19))
    q[:, 6] = 1.0
    q[:, 7:] = np.cumsum(rng.normal(scale=0.01, size=(n, 12)), axis=0)
    v = rng.normal(size=(n, 18))
    tau = rng.normal(size=(n, 12))
    u = rng.normal(size=(n, 12))
    c = np.ones((n, 4), dtype=bool)
    c[150:, 0] = False
    return t, q, v, tau, u, c


def _online(t, q, v, tau, u, c):
    from ciml_learning.core.filters import OnlineStateFilter

    f = OnlineStateFilter(FS)
    outs = [s for k in range(len(t)) for s in f.push(t[k], q[k], v[k], tau[k], u[k], c[k])]
    # every output is counted once, valid or with the reason it is not (state_filter's /diagnostics)
    assert len(outs) == f.counts["valid"] + f.counts["contact_change"] + f.counts["bridged_gap_window"]
    assert f.counts["valid"] == sum(s.valid for s in outs)
    return outs, f.counts


def _assert_online_equals_offline(outs, off):
    index = {round(x * 1e9): i for i, x in enumerate(off.t)}
    assert outs
    for s in outs:
        i = index[round(s.t * 1e9)]
        np.testing.assert_allclose(s.q, off.q[i], atol=1e-9)
        np.testing.assert_allclose(s.a, off.a[i], atol=1e-9)
        np.testing.assert_allclose(s.u, off.u[i], atol=1e-9)
        assert s.valid == off.valid[i] and s.effort_valid == off.effort_valid[i]


def test_online_state_filter_matches_offline_log():
    n = 300
    t, q, v, tau, u, c = _state_log(n)
    off = filter_state_log(t, q, v, tau, u, c)
    outs, counts = _online(t, q, v, tau, u, c)
    assert [s.t for s in outs] == list(t[15:n - 15])
    _assert_online_equals_offline(outs, off)
    assert counts["contact_change"] == off.invalid_counts["contact_change"] > 0  # the same reasons as offline
    # the torques stay usable across the contact change (Γ = τ − u does not see the contacts)
    near_change = ~off.valid & off.effort_valid
    assert near_change[135:165].all() and not off.valid[140:160].any()
    assert counts["effort_valid"] == sum(s.effort_valid for s in outs) == off.effort_valid[15:n - 15].sum()


def test_dropped_samples_are_bridged_alike_online_and_offline():
    """Lost messages (up to MAX_FILLED_SAMPLES in a row) cost no window of output; a longer gap does."""
    n = 300
    t, q, v, tau, u, c = _state_log(n)
    keep = np.ones(n, dtype=bool)
    keep[[100, 200, 201]] = False          # bridged: one and two missing samples
    keep[250:250 + MAX_FILLED_SAMPLES + 1] = False  # one too many: the filter restarts
    t, q, v, tau, u, c = (x[keep] for x in (t, q, v, tau, u, c))
    off = filter_state_log(t, q, v, tau, u, c)
    assert off.invalid_counts["filled_samples"] == 3
    assert off.invalid_counts["time_gap_segments"] == 1
    assert len(off.t) == keep.sum() and np.all(np.isfinite(off.a))
    outs, counts = _online(t, q, v, tau, u, c)
    _assert_online_equals_offline(outs, off)
    assert counts["bridged_gap_window"] == off.invalid_counts["bridged_gap_window"] > 0
    out_t = {round(s.t * 1e9) for s in outs}
    # the samples around the bridged gaps are output; the filled instants are not
    assert round(99 / FS * 1e9) in out_t and round(101 / FS * 1e9) in out_t and round(100 / FS * 1e9) not in out_t
    # outputs whose window saw interpolated input are not for training
    valid_t = {round(s.t * 1e9) for s in outs if s.valid}
    assert round(101 / FS * 1e9) not in valid_t and round(116 / FS * 1e9) in valid_t
    effort_t = {round(s.t * 1e9) for s in outs if s.effort_valid}  # nor for the actuation error's
    assert round(101 / FS * 1e9) not in effort_t and round(116 / FS * 1e9) in effort_t
    assert off.invalid_counts["bridged_gap_window"] > 0
    # interpolation is exact for a linear signal: a bridged gap leaves a ramp's filtered value intact
    ramp = np.arange(n) / FS
    q2 = np.zeros((n, 19))
    q2[:, 6] = 1.0
    q2[:, 7:] = ramp[:, None]
    v2 = np.ones((n, 18))
    lin = filter_state_log(np.arange(n)[keep] / FS, q2[keep], v2[keep], v2[keep, :12], v2[keep, :12],
                           np.ones((keep.sum(), 4), bool))
    k = int(np.flatnonzero(np.isclose(lin.t, 101 / FS))[0])
    np.testing.assert_allclose(lin.q[k, 7:], 101 / FS, atol=1e-12)
    np.testing.assert_allclose(lin.a[k], 0.0, atol=1e-9)


# --- filters designed for the log's measured rate ---------------------------------------

RATES = (250.0, 448.0, 500.0, 1000.0)


def _signal(t):
    """A gait-like signal with known first and second derivatives."""
    f = np.array([0.6, 1.5, 2.7])
    a = np.array([0.2, 0.1, 0.04])
    w = 2 * np.pi * f
    x = (a * np.sin(w * t[:, None] + 0.3)).sum(1)
    xd = (a * w * np.cos(w * t[:, None] + 0.3)).sum(1)
    xdd = -(a * w ** 2 * np.sin(w * t[:, None] + 0.3)).sum(1)
    return x, xd, xdd


def test_window_is_specified_in_seconds():
    from ciml_learning.core.filters import WINDOW_S, taps_for_rate

    assert taps_for_rate(250.0) == 31  # the paper's filter at its rate
    for fs in RATES:
        n = taps_for_rate(fs)
        assert n % 2 == 1 and abs(n / fs - WINDOW_S) <= 1.0 / fs + 1e-9
        f_stop = np.linspace(20, fs / 2, 300)
        _, h = scipy.signal.freqz(lowpass_taps(fs), worN=f_stop, fs=fs)
        assert np.max(20 * np.log10(np.abs(h))) <= -20.0, fs


@pytest.mark.parametrize("fs", RATES)
def test_derivatives_are_the_same_at_every_rate(fs):
    """q̈ of a log at 250, 448, 500 or 1000 Hz matches the true derivative within 1 % of its
    amplitude (a silent 250 Hz design would scale it by 250/fs)."""
    t = np.arange(int(8 * fs)) / fs
    x, xd, xdd = _signal(t)
    for target, true in ((x, xd), (xd, xdd)):
        y, valid = filter_offline(target, derivative_taps(fs))
        assert np.max(np.abs(y[valid] - true[valid])) <= 0.01 * np.max(np.abs(true)), fs


def test_448_hz_log_equals_its_250_hz_resampling():
    from ciml_learning.core.stamps import resample

    t = np.arange(int(8 * 448)) / 448.0
    x, xd, _ = _signal(t)
    n = len(t)
    q = np.zeros((n, 19))
    q[:, 6] = 1.0
    q[:, 7] = x
    v = np.zeros((n, 18))
    v[:, 6] = xd
    tau = np.tile(x[:, None], (1, 12))
    c = np.ones((n, 4), bool)
    fast = filter_state_log(t, q, v, tau, tau, c)  # rate measured from the stamps
    assert fast.rate_hz == pytest.approx(448.0)
    t2, qs = resample(t, q, 250.0)
    _, vs = resample(t, v, 250.0)
    _, ts = resample(t, tau, 250.0)
    slow = filter_state_log(t2, qs, vs, ts, ts, np.ones((len(t2), 4), bool), fs=250.0)
    ok = slow.valid & (t2 > t[0] + 0.2) & (t2 < t[-1] - 0.2)
    a_fast = np.interp(t2[ok], t[fast.valid], fast.a[fast.valid, 6])
    tdot_fast = np.interp(t2[ok], t[fast.valid], fast.tau_dot[fast.valid, 0])
    scale = np.max(np.abs(slow.a[ok, 6]))
    assert np.max(np.abs(a_fast - slow.a[ok, 6])) <= 0.01 * scale
    assert np.max(np.abs(tdot_fast - slow.tau_dot[ok, 0])) <= 0.01 * np.max(np.abs(slow.tau_dot[ok, 0]))


def test_stamp_problems_are_counted():
    from ciml_learning.core.stamps import measure_rate

    t = np.arange(1000) / 448.0 + 5.0
    t = np.delete(t, [100, 101, 102])       # a gap of 4 periods
    t = np.insert(t, 500, t[500])            # a duplicate
    t[700] = t[699] + 0.1 / 448.0            # a burst
    t[800] = 0.0                             # a zero stamp (also going backwards)
    rep = measure_rate(t)
    assert rep.rate_hz == pytest.approx(448.0, rel=1e-6)
    # gaps: the deleted samples, the step after the burst (1.9 periods), the step back up from 0
    assert (rep.gaps, rep.duplicates, rep.zero_stamps) == (3, 1, 1) and rep.bursts >= 1 and rep.non_monotonic == 1
    assert any("gap" in p for p in rep.problems())
    assert measure_rate(np.arange(10) / 250.0).problems() == []  # a clock starting at 0 is fine
