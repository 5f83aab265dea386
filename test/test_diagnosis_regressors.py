"""Each candidate effect's regressor reproduces the simulation's ground truth of that effect.

Force effects: the generalized force recorded under /sim/effect/<label> (GroundTruth of the
plant). Measurement effects (encoder offset, IMU tilt) exert no force; for them the exact
model error they cause is rebuilt from /sim/contact_forces and the known offset, and compared
in the eq. (11) coordinates. The tests read /sim/; the diagnosis never does.
"""
from __future__ import annotations

import os
import sys

import numpy as np
import pinocchio as pin
import pytest

sys.path.insert(0, os.path.dirname(__file__))
from diag_data import read_ground_truth, record_plant_bag  # noqa: E402

from ciml_learning.core.extraction import observation_operators  # noqa: E402
from ciml_learning.core.filters import filter_offline, lowpass_taps  # noqa: E402
from ciml_learning.core.projection import contact_invariant_bases  # noqa: E402
from ciml_learning.core.robot import load_robot  # noqa: E402
from ciml_learning.diagnosis.candidates import (  # noqa: E402
    N_ACT,
    FeatureLayout,
    RegressorEvaluator,
    actuation_features,
    coulomb_regressor,
    link_inertias,
)
from ciml_learning.diagnosis.effects import feature_coefficients  # noqa: E402
from ciml_learning.logs.pipeline import load_dataset  # noqa: E402

ROBOT = load_robot()

FORCE_EFFECTS = [
    {"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0},
    {"type": "joint_viscous_friction", "joint": "lh_hfe_joint", "value": 4.0},
    {"type": "actuator_lag", "joints": "all", "time_constant": 0.012},
    {"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.85},
    {"type": "torque_offset", "joint": "rh_kfe_joint", "value": 3.0},
    {"type": "payload", "mass": 6.0, "com": [0.15, 0.0, 0.05]},
]
OTHER_EFFECTS = [
    {"type": "link_mass_scale", "link": "lf_lowerleg", "value": 1.4},
    {"type": "encoder_offset", "joint": "rf_hfe_joint", "value": 0.02},
    {"type": "base_imu_tilt", "roll": 0.01, "pitch": -0.005},
]
PARAM_KEYS = ("type", "joint", "joints", "link")


def as_diagnosis_effect(e: dict) -> dict:
    """A scenario effect in diagnosis.json form ({type, location, params})."""
    out = {k: e[k] for k in ("type", "joint", "joints", "link") if k in e}
    out["params"] = {k: v for k, v in e.items() if k not in PARAM_KEYS}
    return out


def labels(effects: list[dict]) -> list[str]:
    """/sim/effect/ labels of scenario effects, as the simulator names them."""
    from ciml_sim.scenario import parse_scenario

    return [e.label for e in parse_scenario({"name": "test", "effects": effects}, ROBOT).effects]


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    d = tmp_path_factory.mktemp("diag_regressors")
    out = {}
    for name, effects in (("force", FORCE_EFFECTS), ("other", OTHER_EFFECTS)):
        path = str(d / name)
        info = record_plant_bag(ROBOT, {"name": "test", "effects": effects}, path, seconds=5.0, seed=1)
        assert not info["fell"]
        out[name] = path
    return out


def regressors(bag: str, effects: list[dict]):
    """Dataset, features at its valid samples, feature coefficients of the effects, filtered GT."""
    ds = load_dataset(ROBOT, [bag], progress=False)
    log, tg = ds.log, ds.targets
    lay = FeatureLayout(ROBOT, link_inertias(ROBOT))
    idx = np.flatnonzero(tg.valid)
    coul = coulomb_regressor(log.v[:, 6:], log.segment)
    E, jac = RegressorEvaluator(ROBOT, lay).chunk(log.q[idx], log.v[idx], log.a[idx], log.contacts[idx],
                                                  tg.residual[idx], coul[idx])
    A = actuation_features(log.tau[idx], log.tau_dot[idx])
    theta, cands = feature_coefficients(lay, [as_diagnosis_effect(e) for e in effects])
    truth = read_ground_truth(ROBOT, bag)
    taps = lowpass_taps(250.0)

    def filtered_truth(topic):
        t, vals = truth[topic]
        f, _ = filter_offline(vals.reshape(len(vals), -1), taps)  # the log's low-pass, for a like-for-like
        k = np.searchsorted(t, log.t[idx] - 1e-6)
        assert np.allclose(t[k], log.t[idx], atol=1e-6)
        return f[k]

    return ds, idx, lay, E, jac, A, theta, cands, filtered_truth, truth


def rel_rms(pred, true):
    return float(np.sqrt(np.mean((pred - true) ** 2)) / np.sqrt(np.mean(true ** 2)))


TOLERANCE = {"joint_coulomb_friction": 0.25}
"""Relative RMS error allowed; 0.1 for the rest. Coulomb friction: MuJoCo's friction is a constraint
(true stiction: any torque within ±f_c while the joint sticks), the regressor a smoothed sign, so
they differ around velocity reversals; its best-fit scale must still be within 10 % of 1."""


def test_force_effect_regressors_match_sim_ground_truth(bags):
    ds, idx, lay, E, jac, A, theta, cands, gt, truth = regressors(bags["force"], FORCE_EFFECTS)
    nj = ROBOT.n_joints
    checked = []
    for e, cand, lab in zip(FORCE_EFFECTS, cands, labels(FORCE_EFFECTS)):
        topic = "/sim/effect/" + lab
        assert topic in truth, f"{topic} missing; have {sorted(truth)}"
        f_true = gt(topic)
        mask = np.zeros(lay.n_features)
        mask[list(cand.features)] = 1.0
        th = theta * mask
        if cand.kind == "rbd":
            f_pred = -np.einsum("nif,f->ni", E, th[:lay.n_rbd])  # force on the robot = −Φ̃
        else:
            gamma = np.einsum("njk,jk->nj", A, th[lay.act0:].reshape(nj, N_ACT))
            f_pred = np.hstack([np.zeros((len(idx), 6)), gamma])  # Sᵀ Γ
        active = np.flatnonzero(np.abs(f_true).max(axis=0) > 1e-9)
        err = rel_rms(f_pred[:, active], f_true[:, active])
        assert err < TOLERANCE.get(e["type"], 0.1), (e["type"], err)
        # and not trivially: the prediction has the right size and sign
        p, t = f_pred[:, active].ravel(), f_true[:, active].ravel()
        assert abs(np.dot(p, t) / np.dot(p, p) - 1.0) < 0.1, (e["type"], np.dot(p, t) / np.dot(p, p))
        checked.append(e["type"])
    assert set(checked) == {e["type"] for e in FORCE_EFFECTS}


def test_link_mass_regressor_matches_sim_ground_truth(bags):
    ds, idx, lay, E, jac, A, theta, cands, gt, truth = regressors(bags["other"], OTHER_EFFECTS)
    cand = cands[0]
    f_true = gt("/sim/effect/" + labels(OTHER_EFFECTS)[0])
    th = np.zeros(lay.n_features)
    th[list(cand.features)] = theta[list(cand.features)]
    f_pred = -np.einsum("nif,f->ni", E, th[:lay.n_rbd])
    assert rel_rms(f_pred, f_true) < 0.05


def test_measurement_effect_regressors_match_exact_model_error(bags):
    """Encoder offset and IMU tilt: Φ̃' they cause (eq. 11 applied to the exact
    RNEA(q_true) − J_c(q_true)ᵀλ − RNEA(q_meas), λ from /sim/contact_forces) vs the linearised
    regressors, with the measured configuration known to be biased by the scenario's values."""
    ds, idx, lay, E, jac, A, theta, cands, gt, truth = regressors(bags["other"], OTHER_EFFECTS)
    log = ds.log
    model, data = ROBOT.model, ROBOT.model.createData()
    lam = gt("/sim/contact_forces").reshape(len(idx), ROBOT.n_feet, 3)
    j = ROBOT.joint_names.index("rf_hfe_joint")
    tilt = pin.rpy.rpyToMatrix(0.01, -0.005, 0.0)
    exact = np.zeros((len(idx), ROBOT.nv))
    for n, k in enumerate(idx):
        qm = log.q[k]
        qt = qm.copy()
        qt[7 + j] -= 0.02
        qt[3:7] = pin.Quaternion(pin.Quaternion(qm[3:7]).matrix() @ tilt.T).coeffs()
        tau = pin.rnea(model, data, qt, log.v[k], log.a[k]).copy()
        pin.computeJointJacobians(model, data, qt)
        pin.updateFramePlacements(model, data)
        for i, f in enumerate(ROBOT.foot_frame_ids):
            tau -= pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3].T @ lam[n, i]
        exact[n] = tau - pin.rnea(model, data, qm, log.v[k], log.a[k])
    th = np.zeros(lay.n_features)
    for cand in cands[1:]:
        th[list(cand.features)] = theta[list(cand.features)]
    pred = np.einsum("nif,f->ni", E, th[:lay.n_rbd])
    O, mask = observation_operators(jac, contact_invariant_bases(jac, ROBOT.leg_joints), log.contacts[idx])
    phi_exact = np.einsum("nij,nj->ni", O, exact)[mask]
    phi_pred = np.einsum("nij,nj->ni", O, pred)[mask]
    assert rel_rms(phi_pred, phi_exact) < 0.05
    # each effect alone is visible: the encoder offset's own part, and the IMU roll that tilts the
    # robot's weight into base_fy (m g sin(roll))
    only_enc = np.zeros(lay.n_features)
    only_enc[list(cands[1].features)] = theta[list(cands[1].features)]
    assert np.abs(np.einsum("nif,f->ni", E, only_enc[:lay.n_rbd])).max() > 0.1
    fy = ROBOT.rbd_error_names.index("base_fy")
    mean_fy = np.mean(np.einsum("nij,nj->ni", O, pred)[:, fy])
    assert abs(abs(mean_fy) - ROBOT.total_mass * 9.81 * np.sin(0.01)) < 1.0


def test_link_inertias_sum_to_the_joint_inertias():
    by_joint = {}
    for link in link_inertias(ROBOT, min_mass=0.0):
        by_joint.setdefault(link.joint, []).append(link.params)
    for j, params in by_joint.items():
        assert np.allclose(np.sum(params, axis=0), ROBOT.model.inertias[j].toDynamicParameters(), atol=1e-4)


def _nonzero_cols(x: np.ndarray) -> set[int]:
    return set(np.flatnonzero(np.abs(x).max(axis=0) > 1e-12).tolist())


def test_torque_sensor_regressors_match_the_simulators_model_error():
    """Torque-sensor gain and offset (the reading, not the actuator): at simulated samples the
    regressors with the scenario's values predict Φ̃ = Sᵀτ_m + Σ J_footᵀ f_foot − RNEA(q, v, v̇) (true
    state, v̇ and contact forces from the simulator) and Γ = τ_m − u, on the joints they act on only."""
    from ciml_sim.plant import Plant
    from ciml_sim.scenario import parse_scenario

    effects = [{"type": "torque_sensor_gain", "joint": "lh_kfe_joint", "value": 0.8},
               {"type": "torque_sensor_offset", "joint": "rf_haa_joint", "value": -3.0}]
    plant = Plant(ROBOT, parse_scenario({"name": "test", "effects": effects}, ROBOT))
    plant.reset()
    q0 = plant.standing_configuration()
    nj, nv = ROBOT.n_joints, ROBOT.nv
    rng = np.random.default_rng(0)
    model, data = ROBOT.model, ROBOT.model.createData()
    Q, V, Vd, TAU, U, PHI = [], [], [], [], [], []
    for k in range(120):
        if k % 10 == 0:  # a new posture target now and then: the joints move and carry load
            plant.set_command(np.zeros(nj), q0[7:] + rng.normal(scale=0.05, size=nj), np.zeros(nj),
                              np.full(nj, 300.0), np.full(nj, 8.0))
        plant.step(4)
        m, g = plant.measure(), plant.ground_truth()
        phi = np.zeros(nv)
        phi[6:] = m.tau_measured
        pin.computeJointJacobians(model, data, g.q)
        pin.updateFramePlacements(model, data)
        for i, f in enumerate(ROBOT.foot_frame_ids):
            phi += pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3].T @ g.contact_forces[i]
        phi -= pin.rnea(model, data, g.q, g.v, g.vdot)
        Q.append(g.q), V.append(g.v), Vd.append(g.vdot), TAU.append(m.tau_measured), U.append(m.u_commanded)
        PHI.append(phi)
    Q, V, Vd, TAU, U, PHI = map(np.asarray, (Q, V, Vd, TAU, U, PHI))
    lay = FeatureLayout(ROBOT, link_inertias(ROBOT))
    n = len(Q)
    E, _ = RegressorEvaluator(ROBOT, lay).chunk(Q, V, Vd, np.zeros((n, ROBOT.n_feet), bool), np.zeros((n, nv)),
                                                np.zeros((n, nj)), tau=TAU)
    theta, cands = feature_coefficients(lay, [as_diagnosis_effect(e) for e in effects])
    assert [c.type for c in cands] == ["torque_sensor_gain", "torque_sensor_offset"]
    pred = np.einsum("nif,f->ni", E, theta[:lay.n_rbd])
    active = [6 + ROBOT.joint_names.index("lh_kfe_joint"), 6 + ROBOT.joint_names.index("rf_haa_joint")]
    assert np.sqrt(np.mean(PHI[:, active] ** 2, axis=0)).min() > 1.0  # the model error is there, and large
    assert rel_rms(pred[:, active], PHI[:, active]) < 0.02
    # elsewhere the prediction is zero and the simulator's model error is at the level of its contact
    # softness (this closure's own floor, ~0.1 Nm), far below the sensor effects'
    assert _nonzero_cols(pred) == set(active)
    assert rel_rms(pred, PHI) < 0.05
    gamma = np.einsum("njk,jk->nj", actuation_features(TAU, np.zeros_like(TAU)), theta[lay.act0:].reshape(nj, N_ACT))
    np.testing.assert_allclose(gamma, TAU - U, atol=1e-9)
