"""Identification machinery of the diagnosis on data with a known answer (no simulator):
bounded least squares, parameter conversions, and selection on synthetic regression rows."""
from __future__ import annotations

import numpy as np
import pytest

from ciml_learning.core.robot import load_robot
from ciml_learning.diagnosis.candidates import N_ACT, N_GENERIC, FeatureLayout, link_inertias, point_mass_rotational
from ciml_learning.diagnosis.effects import DiagnosisError, EffectModel, feature_coefficients
from ciml_learning.diagnosis.features import Grams, Rows, grams
from ciml_learning.diagnosis.identification import (
    Model,
    bounded_least_squares,
    fit_model,
    physical_parameters,
    select,
)

ROBOT = load_robot()
LAYOUT = FeatureLayout(ROBOT, link_inertias(ROBOT))


def test_bounded_least_squares_matches_unconstrained_inside_and_respects_bounds():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(200, 4))
    theta = np.array([1.0, -2.0, 0.5, 3.0])
    y = X @ theta + 0.01 * rng.normal(size=200)
    H, c = X.T @ X, X.T @ y
    free = bounded_least_squares(H, c, np.full(4, -np.inf), np.full(4, np.inf))
    assert np.allclose(free, np.linalg.solve(H, c), atol=1e-8)
    lo = np.array([0.0, 0.0, -np.inf, -np.inf])
    boxed = bounded_least_squares(H, c, lo, np.full(4, np.inf))
    assert boxed[1] == pytest.approx(0.0, abs=1e-8) and boxed[0] > 0
    # KKT: the free coordinates are optimal given the active bound
    grad = H @ boxed - c
    assert np.allclose(grad[[0, 2, 3]], 0.0, atol=1e-6) and grad[1] > 0


def test_parameter_conversions_round_trip():
    effects = [
        {"type": "torque_gain", "joint": "rh_hfe_joint", "params": {"value": 0.8}},
        {"type": "torque_offset", "joint": "rh_hfe_joint", "params": {"value": 2.5}},
        {"type": "actuator_lag", "joint": "rh_hfe_joint", "params": {"time_constant": 0.01}},
        {"type": "payload", "params": {"mass": 6.0, "com": [0.15, 0.0, 0.05]}},
        {"type": "link_mass_scale", "link": "lf_lowerleg", "params": {"value": 1.4}},
        {"type": "joint_coulomb_friction", "joint": "lf_kfe_joint", "params": {"value": 5.0}},
        {"type": "base_imu_tilt", "params": {"roll": 0.01, "pitch": -0.005}},
    ]
    theta_f, cands = feature_coefficients(LAYOUT, effects)
    # the internal parameters of each candidate, read back from the feature coefficients
    thetas = []
    for e, c in zip(effects, cands):
        A = LAYOUT.matrix(c, np.array(e["params"]["com"]) if c.type == "payload" else None)
        thetas.append(np.linalg.lstsq(A, theta_f * (A.sum(axis=1) != 0), rcond=None)[0])
    model = Model(LAYOUT, cands, np.concatenate(thetas), payload_com=np.array([0.15, 0.0, 0.05]))
    back = physical_parameters(model)
    for e, p in zip(effects, back):
        for k, v in e["params"].items():
            assert np.allclose(p[k], v, rtol=1e-9), (e["type"], k, p[k], v)
    # Γ = τ − u of g·lag(u) + o at steady state (τ̇ = 0): u = (τ − o)/g
    tau = np.full(ROBOT.n_joints, 40.0)
    gamma = EffectModel(ROBOT, effects).actuation_error(tau, np.zeros(ROBOT.n_joints))
    j = ROBOT.joint_names.index("rh_hfe_joint")
    assert gamma[j] == pytest.approx(40.0 - (40.0 - 2.5) / 0.8)
    with pytest.raises(DiagnosisError):
        EffectModel(ROBOT, [{"type": "torque_gain", "joint": "nope", "params": {"value": 0.9}}])


def test_point_mass_rotational_inertia():
    c = np.array([0.1, -0.2, 0.3])
    ixx, ixy, iyy, ixz, iyz, izz = point_mass_rotational(c)
    assert ixx == pytest.approx(0.04 + 0.09) and ixy == pytest.approx(0.02) and izz == pytest.approx(0.05)
    assert iyz == pytest.approx(0.06) and ixz == pytest.approx(-0.03) and iyy == pytest.approx(0.1)


def _synthetic_rows(rng, theta_true: dict[int, float], n: int = 3000, noise: float = 0.05) -> Rows:
    """Rows with random features and Γ = Σ features·θ + noise on the actuation part only."""
    nj = ROBOT.n_joints
    X_act = np.zeros((n, nj, N_ACT))
    X_act[:, :, :2] = rng.normal(size=(n, nj, 2))
    X_act[:, :, 2] = 1.0
    theta = np.zeros(LAYOUT.n_features)
    for f, v in theta_true.items():
        theta[f] = v
    act_theta = theta[LAYOUT.act0:].reshape(nj, N_ACT)
    y_act = np.einsum("njk,jk->nj", X_act, act_theta) + noise * rng.normal(size=(n, nj))
    nr = LAYOUT.n_rbd
    return Rows(LAYOUT, np.arange(n), np.zeros((0, nr), np.float32), np.zeros(0), np.zeros(0, int),
                np.zeros(0, int), X_act, y_act, np.zeros(0))


def test_selection_names_the_true_actuation_effects_and_nothing_else():
    rng = np.random.default_rng(1)
    j = ROBOT.joint_names.index("lh_kfe_joint")
    truth = {LAYOUT.actuation_feature(j, "gain"): 0.3, LAYOUT.actuation_feature(2, "offset"): 1.0}
    tr, ho = _synthetic_rows(rng, truth), _synthetic_rows(rng, truth)
    sel = select(LAYOUT, grams(tr), grams(ho))
    labels = sorted(c.label for c in sel.effects)
    assert labels == sorted(["torque_gain:lh_kfe_joint", f"torque_offset:{ROBOT.joint_names[2]}"])
    assert sel.unexplained_share < 0.05  # the noise (1 per normalised row) is all that is left
    assert abs(sum(sel.shares) + sel.unexplained_share - 1.0) < 1e-9
    params = dict(zip([c.label for c in sel.model.candidates], physical_parameters(sel.model)))
    assert params["torque_gain:lh_kfe_joint"]["value"] == pytest.approx(1 / (1 - 0.3), rel=0.01)


def test_selection_names_nothing_on_pure_noise():
    rng = np.random.default_rng(2)
    tr, ho = _synthetic_rows(rng, {}), _synthetic_rows(rng, {})
    sel = select(LAYOUT, grams(tr), grams(ho))
    # noise is not an unexplained effect: the gap is at the noise floor (all of the residual is noise)
    assert sel.effects == [] and sel.gap_at_noise_floor and sel.unexplained_share == 0.0
    assert sel.unexplained_share_with_noise == pytest.approx(1.0)


def _joint_torque_rows(rng, truth: str, n: int = 3000, noise: float = 0.05) -> Rows:
    """Φ̃' rows at one joint (j = 4) whose error is a viscous friction ("viscous") or a torque
    linear in the joint position ("spring", outside the catalogue); an encoder-offset column
    correlated with the position is the catalogue's best stand-in for the spring."""
    j, nr = 4, LAYOUT.n_rbd
    z, qd = rng.normal(size=n), rng.normal(size=n)
    X = np.zeros((n, nr))
    X[:, LAYOUT.viscous0 + j] = qd
    X[:, LAYOUT.coulomb0 + j] = np.tanh(3 * qd)
    X[:, LAYOUT.encoder0 + j] = 0.7 * z + 0.7 * rng.normal(size=n)
    g0 = LAYOUT.generic0 + N_GENERIC * j
    X[:, g0:g0 + N_GENERIC] = np.stack([np.ones(n), z, z ** 2, z ** 3], axis=1)
    y = 3.0 * (qd if truth == "viscous" else z) + noise * rng.normal(size=n)
    nj = ROBOT.n_joints
    return Rows(LAYOUT, np.arange(n), X.astype(np.float32), y, rng.integers(0, 6, n), np.arange(n),
                np.zeros((n, nj, N_ACT)), noise * rng.normal(size=(n, nj)), np.zeros(n))


def test_out_of_catalogue_probe_takes_a_spring_but_not_a_catalogue_effect():
    """A position-dependent joint torque goes to the probe (unexplained), not to the encoder offset
    that explains half of it; a viscous friction is named as such, the probe stays out."""
    rng = np.random.default_rng(4)
    tr, ho = _joint_torque_rows(rng, "spring"), _joint_torque_rows(rng, "spring")
    sel = select(LAYOUT, grams(tr), grams(ho))
    assert [c.label for c in sel.effects] == [f"unmodelled_joint_torque:{ROBOT.joint_names[4]}"]
    assert not sel.effects[0].in_catalogue
    tr, ho = _joint_torque_rows(rng, "viscous"), _joint_torque_rows(rng, "viscous")
    sel = select(LAYOUT, grams(tr), grams(ho))
    assert [c.label for c in sel.effects] == [f"joint_viscous_friction:{ROBOT.joint_names[4]}"]
    assert physical_parameters(sel.model)[1]["value"] == pytest.approx(3.0, rel=0.01)


def test_fit_with_payload_refines_the_rotational_inertia():
    """Grams of an exact payload regressor: the fitted CoM converges to the true one."""
    rng = np.random.default_rng(3)
    com = np.array([0.15, 0.0, 0.05])
    dpi = np.concatenate([[6.0], 6.0 * com, 6.0 * point_mass_rotational(com)])
    nf = LAYOUT.n_features
    X = np.zeros((4000, nf))
    X[:, LAYOUT.root0:LAYOUT.root0 + 10] = rng.normal(size=(4000, 10))
    y = X[:, LAYOUT.root0:LAYOUT.root0 + 10] @ dpi
    g = Grams(G=(X.T @ X)[None], c=(X.T @ y)[None], s=np.array([y @ y]), n=np.array([4000.0]))
    cand = next(c for c in LAYOUT.candidates if c.type == "payload")
    m = fit_model(LAYOUT, [cand], g.G[0], g.c[0])
    p = physical_parameters(m)[0]
    assert p["mass"] == pytest.approx(6.0, rel=1e-6) and np.allclose(p["com"], com, atol=1e-6)
