"""Calibrated uncertainty and physical bounds of the diagnosis, on data with a known answer (no simulator).

- intervals from the block bootstrap (the diagnosis' own functions) cover the truth as often as they
  claim on linear regressions with autocorrelated (AR(1)) regressors and noise;
- every catalogue parameter has its physical bound (bounds.py), and an estimate on a bound is
  "at bound — not identified", never an effect;
- the actuator lag's reading of a staircase command (staircase_reading) is what a regression of
  Γ = τ − u on the filtered τ̇ gives on a simulated lag, at any phase of the samples in the
  command period, and lag_time_constant inverts it exactly.
"""
from __future__ import annotations

import numpy as np
import pytest

from ciml_learning.core.robot import load_robot
from ciml_learning.diagnosis import bounds
from ciml_learning.diagnosis import uncertainty as unc
from ciml_learning.diagnosis.candidates import N_ACT, FeatureLayout, link_inertias
from ciml_learning.diagnosis.features import Rows, grams
from ciml_learning.diagnosis.identification import (
    CommandSampling,
    fit_model,
    lag_reading,
    lag_time_constant,
    physical_parameters,
    select,
    staircase_reading,
)

ROBOT = load_robot()
LAYOUT = FeatureLayout(ROBOT, link_inertias(ROBOT))


def _ar1(rng, n: int, phi: float) -> np.ndarray:
    e = rng.normal(size=n) * np.sqrt(1 - phi ** 2)
    x = np.empty(n)
    x[0] = rng.normal()
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return x


def _coverage_trial(rng, n: int = 5000, fs: float = 250.0) -> np.ndarray:
    """|θ̂ − θ| / std of one synthetic regression: smooth regressors, AR(1) noise (φ = 0.95, ~0.16 s)."""
    X = np.stack([_ar1(rng, n, 0.98), _ar1(rng, n, 0.9), np.ones(n)], axis=1)
    theta = np.array([1.0, -0.5, 0.2])
    y = X @ theta + _ar1(rng, n, 0.95)
    est = np.linalg.lstsq(X, y, rcond=None)[0]
    sub = unc.block_length([y - X @ est], fs, n)
    nb = int(np.ceil(n / sub))
    Gb = np.stack([X[b * sub:(b + 1) * sub].T @ X[b * sub:(b + 1) * sub] for b in range(nb)])
    cb = np.stack([X[b * sub:(b + 1) * sub].T @ y[b * sub:(b + 1) * sub] for b in range(nb)])
    draws = unc.block_bootstrap(Gb, cb, lambda G, c: np.linalg.solve(G, c), 100, int(rng.integers(1 << 30)))
    return np.abs(est - theta) / unc.bootstrap_std(draws, nb)


def test_intervals_cover_the_truth_under_autocorrelated_noise():
    rng = np.random.default_rng(0)
    z = np.array([_coverage_trial(rng) for _ in range(200)])
    cov95, cov68 = (z <= 1.959964).mean(), (z <= 0.994458).mean()
    assert cov95 >= 0.90 and (z <= 1.959964).mean(axis=0).min() >= 0.85, (z <= 1.959964).mean(axis=0)
    assert cov68 >= 0.60
    # the correlation the blocks are sized by: τ_int = (1 + φ)/(1 − φ) for AR(1), 1 for white noise
    assert unc.integrated_autocorrelation_time(_ar1(rng, 20000, 0.95)) == pytest.approx(39.0, rel=0.25)
    assert unc.integrated_autocorrelation_time(rng.normal(size=20000)) < 1.2


def _lagged_staircase(T: float, period: float, rate: float, offset: float, share: float = 1.0):
    """A first-order lag T of a command whose share `share` is a staircase (held for `period`) and the
    rest continuous, sampled at `rate` from `offset` after a command instant; exact within each hold
    (a 0.1 ms grid), each sample paired with the command in force (strictly before it).
    Returns t, the torque τ and the command u in force at the samples."""
    dt = 1e-4
    t = np.arange(0.0, 20.0, dt)
    s = sum(a * np.sin(2 * np.pi * f * t + p) for a, f, p in ((30, 0.7, 0.0), (20, 1.9, 1.0), (10, 3.1, 2.0)))
    held = s[(np.floor(t / period + 1e-9) * period / dt).round().astype(int)]  # the staircase: value at its update
    u = share * held + (1 - share) * s
    a = np.exp(-dt / T)
    tau = np.empty_like(u)
    tau[0] = u[0]
    for k in range(1, len(t)):  # exact for u constant over each dt step (u[k−1] acts on [t_{k−1}, t_k))
        tau[k] = a * tau[k - 1] + (1 - a) * u[k - 1]
    idx = np.round((offset + np.arange(0.0, 19.9 - offset, 1.0 / rate)) / dt).astype(int)
    return t[idx], tau[idx], u[idx - 1]


@pytest.mark.parametrize("rate,offset,share", [(250.0, 0.004, 1.0), (250.0, 0.002, 1.0), (250.0, 0.001, 1.0),
                                               (1000.0, 0.001, 1.0), (250.0, 0.004, 0.0), (250.0, 0.004, 0.5)])
def test_lag_reading_is_what_the_regression_on_the_filtered_torque_rate_reads(rate, offset, share):
    """c of Γ = τ − u = −c τ̇ (τ̇ by the diagnosis' own low-pass differentiator) on a simulated lag of
    10 ms: lag_reading at the samples' phases, within 1 %; 7.7 ms for a staircase sampled on its
    command instants, 10 ms for a continuous command."""
    from ciml_learning.core.filters import derivative_taps, filter_offline

    T, period = 0.010, 0.004
    t, tau, u = _lagged_staircase(T, period, rate, offset, share)
    tau_dot, ok = filter_offline(tau, derivative_taps(rate))
    gamma, _ = filter_offline(tau - u, np.eye(1, len(derivative_taps(rate)), (len(derivative_taps(rate)) - 1) // 2)[0])
    c = -np.sum(gamma[ok] * tau_dot[ok]) / np.sum(tau_dot[ok] ** 2)
    phase = np.round(((t - 1e-9) % period + 1e-9) / period, 6)  # φ/Δ ∈ (0, 1]: time since the paired command
    phase[phase == 0] = 1.0
    x, n = np.unique(phase, return_counts=True)
    sampling = CommandSampling(period, x, n / n.sum(), {"all": share}, 1.0 / rate)
    assert c == pytest.approx(lag_reading(T, sampling), rel=0.01)
    assert lag_time_constant(c, sampling)[0] == pytest.approx(T, rel=0.01)


def test_lag_conversion_inverts_the_reading_exactly():
    period = 0.004
    uniform = (np.arange(400) + 0.5) / 400
    for T in (0.0005, 0.002, 0.01, 0.02, 0.05):
        beta = np.exp(-period / T)
        # on the command instants: Δβ/(1 − β) ≈ T − Δ/2; uniform phases: T
        assert staircase_reading(T, period, np.array([1.0]), np.array([1.0])) == pytest.approx(
            period * beta / (1 - beta), rel=1e-12)
        assert staircase_reading(T, period, uniform, np.full(400, 1 / 400)) == pytest.approx(T, rel=1e-4)
        for phase, share in (([1.0], 1.0), ([0.5], 1.0), ([0.25, 0.5, 0.75, 1.0], 0.7), ([1.0], 0.0)):
            x = np.array(phase)
            s = CommandSampling(period, x, np.full(len(x), 1 / len(x)), {"all": share, "j": 0.2}, 0.001)
            for joint in (None, "j"):
                T_back, std = lag_time_constant(lag_reading(T, s, joint), s, joint)
                assert T_back == pytest.approx(T, rel=1e-9) and std == pytest.approx(0.001 / np.sqrt(12))
    assert staircase_reading(0.0, period, np.array([1.0]), np.array([1.0])) == 0.0  # no lag reads no lag
    assert lag_time_constant(0.0077, None) == (0.0077, 0.0)  # no command period known: the raw coefficient
    on_ticks = CommandSampling(period, np.array([1.0]), np.array([1.0]), {"all": 1.0}, period)
    assert lag_time_constant(-1e-4, on_ticks) == (0.0, 0.0)


@pytest.mark.parametrize("typ", ["joint_coulomb_friction", "joint_viscous_friction", "encoder_offset", "base_imu_tilt",
                                 "payload", "link_mass_scale", "actuator_lag", "torque_gain", "torque_offset",
                                 "torque_sensor_gain", "torque_sensor_offset"])
def test_every_catalogue_parameter_has_its_physical_bound(typ):
    cands = [c for c in LAYOUT.candidates if c.type == typ]
    assert cands
    for c in cands:
        lo, hi = np.asarray(c.lower), np.asarray(c.upper)
        assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(lo <= 0) and np.all(hi >= 0)
        assert np.all(hi > lo)
    c = cands[0]
    lim = float(ROBOT.torque_limits[0])
    if typ == "joint_coulomb_friction" or typ == "joint_viscous_friction":
        assert c.lower == (0.0,) and c.upper[0] == pytest.approx(bounds.FRICTION_FRACTION * lim)
    elif typ in ("encoder_offset", "base_imu_tilt"):
        assert np.allclose(c.upper, np.radians(5.0)) and np.allclose(c.lower, -np.radians(5.0))
    elif typ == "payload":
        assert c.lower[0] == 0.0 and c.upper[0] == pytest.approx(ROBOT.total_mass * bounds.PAYLOAD_MASS_FRACTION)
    elif typ == "link_mass_scale":
        assert 1 + c.lower[0] == pytest.approx(0.2) and 1 + c.upper[0] == pytest.approx(5.0)
    elif typ == "actuator_lag":
        assert c.lower == (0.0,) and c.upper[0] == pytest.approx(bounds.MAX_LAG / bounds.TORQUE_GAIN[0])
    elif typ in ("torque_gain", "torque_sensor_gain"):
        assert 1 / (1 - c.lower[0]) == pytest.approx(0.5) and 1 / (1 - c.upper[0]) == pytest.approx(2.0)
    else:
        assert c.upper[0] == pytest.approx(bounds.OFFSET_FRACTION * lim / bounds.TORQUE_GAIN[0])
    # the baseline keeps the signs its theory gives
    b = LAYOUT.baseline
    assert b.upper == (0.0, 0.0, 0.0) and b.lower[2] == -bounds.MAX_TICK / 2


def test_fit_stays_inside_the_bounds_and_an_estimate_on_a_bound_is_not_identified():
    """A joint's Γ is 4 τ (a 'gain' of 1/(1 − 4) < 0, outside every physical range): the torque gain
    ends on its bound and is reported as not identified, never as an effect."""
    rng = np.random.default_rng(5)
    j = 3
    n = 3000

    def rows():
        X_act = np.zeros((n, ROBOT.n_joints, N_ACT))
        X_act[:, :, :2] = rng.normal(size=(n, ROBOT.n_joints, 2))
        X_act[:, :, 2] = 1.0
        y = 0.05 * rng.normal(size=(n, ROBOT.n_joints))
        y[:, j] += 4.0 * X_act[:, j, 1]
        nr = LAYOUT.n_rbd
        return Rows(LAYOUT, np.arange(n), np.zeros((0, nr), np.float32), np.zeros(0), np.zeros(0, int),
                    np.zeros(0, int), X_act, y, np.zeros(0))

    tr, ho = grams(rows()), grams(rows())
    gain = next(c for c in LAYOUT.candidates if c.type == "torque_gain" and c.joint == ROBOT.joint_names[j])
    G, c, _ = tr.weighted(np.ones(len(tr.s)))
    m = fit_model(LAYOUT, [gain], G, c)
    assert m.theta[0] == pytest.approx(gain.upper[0])  # on the bound, not 4
    assert physical_parameters(m)[0]["value"] == pytest.approx(bounds.TORQUE_GAIN[1])
    sel = select(LAYOUT, tr, ho)
    named = {(e.type, e.joint) for e in sel.effects}
    assert ("torque_gain", ROBOT.joint_names[j]) not in named
    flagged = [e for e in sel.not_identified if e["type"] == "torque_gain" and e["joint"] == ROBOT.joint_names[j]]
    assert flagged and flagged[0]["status"] == "at bound — not identified" and flagged[0]["confidence"] is None
