"""The effect registry (ciml_learning.effects, issue 29): every type converts θ ↔ physical both ways,
and joint Stribeck friction — added through the registry alone — is identified with its three
parameters and intervals on synthetic rows that follow it, while Coulomb-only rows stay Coulomb."""
from __future__ import annotations

import numpy as np
import pytest

from ciml_learning.core.robot import load_robot
from ciml_learning.diagnosis.candidates import N_ACT, FeatureLayout, link_inertias
from ciml_learning.diagnosis.effects import feature_coefficients
from ciml_learning.diagnosis.features import Rows, grams
from ciml_learning.diagnosis.identification import Model, parameter_uncertainty, physical_parameters, select
from ciml_learning.effects import CATALOGUE, EFFECTS, EffectTypeError, Refinement, effect_type
from ciml_learning.effects.base import COULOMB_SMOOTHING
from ciml_learning.effects.joint_stribeck_friction import STRIBECK_VELOCITIES

ROBOT = load_robot()
LAYOUT = FeatureLayout(ROBOT, link_inertias(ROBOT))
J = 4
JOINT = ROBOT.joint_names[J]
EXAMPLE = {  # one effect of each catalogue type, in the diagnosis' terms
    "payload": {"params": {"mass": 6.0, "com": [0.15, 0.0, 0.05]}},
    "joint_coulomb_friction": {"joint": "lf_kfe_joint", "params": {"value": 5.0}},
    "joint_viscous_friction": {"joint": "lh_hfe_joint", "params": {"value": 4.0}},
    "actuator_lag": {"joint": "rh_hfe_joint", "params": {"time_constant": 0.01}},
    "torque_gain": {"joint": "rh_hfe_joint", "params": {"value": 0.8}},
    "torque_offset": {"joint": "rh_hfe_joint", "params": {"value": 2.5}},
    "link_mass_scale": {"link": "lf_lowerleg", "params": {"value": 1.4}},
    "encoder_offset": {"joint": "rf_hfe_joint", "params": {"value": 0.02}},
    "base_imu_tilt": {"params": {"roll": 0.01, "pitch": -0.005}},
    "torque_sensor_gain": {"joint": "lh_kfe_joint", "params": {"value": 0.9}},
    "torque_sensor_offset": {"joint": "lh_kfe_joint", "params": {"value": 2.0}},
    "joint_stribeck_friction": {"joint": "rf_kfe_joint",
                                "params": {"breakaway": 12.0, "coulomb": 4.0, "velocity": 0.15}},
}


def test_registry_round_trip_of_every_catalogue_type():
    assert set(EXAMPLE) == set(CATALOGUE)
    effects = [{"type": t, **e} for t, e in EXAMPLE.items()]
    theta_f, cands = feature_coefficients(LAYOUT, effects)
    thetas, nonlinear = [], {}
    for e, c in zip(effects, cands):
        if "velocity" in e["params"]:
            nonlinear[c.label] = e["params"]["velocity"]
        A = LAYOUT.matrix(c, np.array(e["params"]["com"]) if c.type == "payload" else None, nonlinear=nonlinear)
        rows = A.any(axis=1)
        own = theta_f.copy()
        if c.type == "joint_stribeck_friction":  # shares its Coulomb column with no other effect here
            own[~rows] = 0.0
        thetas.append(np.linalg.lstsq(A[rows], own[rows], rcond=None)[0])
    model = Model(LAYOUT, cands, np.concatenate(thetas), payload_com=np.array([0.15, 0.0, 0.05]), nonlinear=nonlinear)
    for e, p in zip(effects, physical_parameters(model)):
        for k, v in e["params"].items():
            assert np.allclose(p[k], v, rtol=1e-9), (e["type"], k, p[k], v)
    with pytest.raises(EffectTypeError, match="valid: payload"):
        effect_type("stiction")


def test_refined_by_names_what_a_candidates_matrix_depends_on():
    """The layout keeps a candidate's A (FeatureLayout.block) unless its type names the Refinement field it
    reads: every other type's A is the same under any refinement, and each named field changes its type's A."""
    one = Refinement()
    other = Refinement(np.array([0.2, -0.1, 0.05]), {j: 0.7 for j in ROBOT.joint_names},
                       {c.label: 0.3 for c in LAYOUT.candidates})
    seen = set()
    for c in LAYOUT.candidates:
        if not c.in_catalogue:
            continue
        a, b = (LAYOUT.matrix(c, *r) for r in (one, other))
        refined_by = EFFECTS[c.type].refined_by
        if refined_by is None:
            assert np.array_equal(a, b), c.label
            rows, kept = LAYOUT.block(c, *other)
            assert LAYOUT.block(c) is LAYOUT.block(c) and np.array_equal(kept, a[rows]), c.label
        elif not np.array_equal(a, b):
            seen.add(c.type)
            rows, fresh = LAYOUT.block(c, *other)
            assert np.array_equal(fresh, b[rows]) and LAYOUT.block(c, *other) is not LAYOUT.block(c, *other)
    assert seen == {t for t in CATALOGUE if EFFECTS[t].refined_by is not None}


def _friction_rows(rng, truth: dict, n: int = 4000, noise: float = 0.05) -> Rows:
    """Φ̃' rows at joint J whose error is a joint friction torque (truth: Stribeck parameters) and the
    columns of every friction candidate there (no low-pass: the rows stand for the filtered log)."""
    nr = LAYOUT.n_rbd
    qd = rng.normal(scale=0.4, size=n)
    X = np.zeros((n, nr))
    c = np.tanh(qd / COULOMB_SMOOTHING)
    X[:, LAYOUT.coulomb0 + J] = c
    X[:, LAYOUT.viscous0 + J] = qd
    k = len(STRIBECK_VELOCITIES)
    s0 = LAYOUT.joint_feature0["joint_stribeck_friction"] + k * J
    X[:, s0:s0 + k] = EFFECTS["joint_stribeck_friction"].joint_features(qd[:, None])[:, 0]
    level = truth["coulomb"] + (truth["breakaway"] - truth["coulomb"]) * np.exp(-(qd / truth["velocity"]) ** 2)
    y = level * c + noise * rng.normal(size=n)
    nj = ROBOT.n_joints
    return Rows(LAYOUT, np.arange(n), X.astype(np.float32), y, rng.integers(0, 6, n), np.arange(n),
                np.zeros((n, nj, N_ACT)), noise * rng.normal(size=(n, nj)), np.zeros(n))


def test_stribeck_friction_named_with_parameters_and_intervals():
    rng = np.random.default_rng(11)
    truth = {"breakaway": 12.0, "coulomb": 4.0, "velocity": 0.15}  # between two velocity columns
    tr, ho = _friction_rows(rng, truth), _friction_rows(rng, truth)
    sel = select(LAYOUT, grams(tr), grams(ho))
    assert [c.label for c in sel.effects] == [f"joint_stribeck_friction:{JOINT}"]
    p = physical_parameters(sel.model)[1]
    stds, info = parameter_uncertainty(sel, tr, grams(ho), n_boot=30)
    std, parts = stds[1], info["components"][1]
    for key, rel in (("breakaway", 0.05), ("coulomb", 0.05), ("velocity", 0.1)):
        assert p[key] == pytest.approx(truth[key], rel=rel), (key, p)
        assert 0 < std[key] < 0.2 * truth[key], (key, std)
        # the components kept for calibration are the ones combined, in quadrature
        assert np.hypot.reduce([c[key] for c in parts.values()]) == pytest.approx(std[key], rel=1e-9)
    assert parts["sampling"]["breakaway"] > 0 and parts["conversion"]["breakaway"] == 0.0


def test_coulomb_friction_rows_are_not_named_stribeck():
    rng = np.random.default_rng(12)
    coulomb_only = {"breakaway": 8.0, "coulomb": 8.0, "velocity": 0.3}
    tr, ho = _friction_rows(rng, coulomb_only), _friction_rows(rng, coulomb_only)
    sel = select(LAYOUT, grams(tr), grams(ho))
    assert [c.label for c in sel.effects] == [f"joint_coulomb_friction:{JOINT}"]
    assert physical_parameters(sel.model)[1]["value"] == pytest.approx(8.0, rel=0.01)
