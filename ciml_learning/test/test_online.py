"""Pure helpers of the online_learner and model_server nodes (no rclpy.init, no DDS)."""
from __future__ import annotations

import os
import threading
import time

import numpy as np
import pinocchio as pin
import pytest

from ciml_learning import conversions as cv
from ciml_learning.conversions import ConversionError
from ciml_learning.dynamics import ReferenceState, ReferenceTorque
from ciml_learning.extraction import dynamics_batch, learning_inputs
from ciml_learning.models import ModelFileError, ModelSet, ModelSetError
from ciml_learning.online import (ERROR, LATEST, NOMINAL, STATE, STAMPS_FILE, ErrorSample, LatestOnlyWorker,
                                  OnlineLearner, SnapshotWriter, StampPairer, StateSample, load_served_model,
                                  model_error_sample, nominal_prediction, predict_at_reference)
from ciml_learning.projection import contact_invariant_bases, generalized_rbd_error, leg_coupling
from ciml_learning.robot import load_robot

ROBOT = load_robot()


def stream(n: int, seed: int = 0):
    """A smooth synthetic stream of states and errors with a known structure (4 ms apart)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 250.0
    nj, nv = ROBOT.n_joints, ROBOT.nv
    ph = rng.uniform(0, 2 * np.pi, nj)
    q = np.zeros((n, ROBOT.nq))
    q[:, 2] = 0.6
    for k in range(n):
        q[k, 3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.05 * np.sin(t[k]), 0.03 * np.cos(t[k]), 0.0)).coeffs()
    q[:, 7:] = ROBOT.standing_joints + 0.2 * np.sin(2 * np.pi * 1.2 * t[:, None] + ph)
    v = np.zeros((n, nv))
    v[:, 6:] = 0.2 * 2 * np.pi * 1.2 * np.cos(2 * np.pi * 1.2 * t[:, None] + ph)
    a = np.zeros((n, nv))
    a[:, 6:] = -0.2 * (2 * np.pi * 1.2) ** 2 * np.sin(2 * np.pi * 1.2 * t[:, None] + ph)
    phase = ((t * 1.5) % 1.0)[:, None]
    swing = (phase >= np.arange(4) / 4) & (phase < (np.arange(4) + 1) / 4)   # a walk: one foot at a time
    observed = np.hstack([np.ones((n, 6), bool), np.repeat(swing, 3, axis=1)])
    phi = np.where(observed, 20 * np.tanh(v[:, :18] + 0.3 * q[:, 7:].sum(axis=1, keepdims=True)), 0.0)
    tau = 30 * np.sin(2 * np.pi * 1.2 * t[:, None] + ph + 1.0)
    tau_dot = 30 * 2 * np.pi * 1.2 * np.cos(2 * np.pi * 1.2 * t[:, None] + ph + 1.0)
    gamma = -3.0 * v[:, 6:] - 0.01 * tau_dot + rng.normal(scale=0.2, size=(n, nj))
    valid = rng.uniform(size=n) > 0.1
    stamps = (np.arange(n) * 4_000_000 + 1_000_000_000).astype(np.int64)
    # the model set's targets, as the extraction makes them from Φ̃' (eq. 8)
    basis = contact_invariant_bases(dynamics_batch(ROBOT, q, v, a)[1], ROBOT.leg_joints)
    rbd, rbd_observed = generalized_rbd_error(basis, phi, observed, ROBOT.leg_joints)
    return dict(q=q, v=v, a=a, tau=tau, tau_dot=tau_dot, phi=phi, observed=observed, gamma=gamma, valid=valid,
                stamps=stamps, contacts=~swing, X=learning_inputs(q, v, a, tau, tau_dot), rbd=rbd, rbd_observed=rbd_observed, basis=basis,
                coupling=leg_coupling(basis, ROBOT.leg_joints))


def state_sample(s, k, valid=None) -> StateSample:
    return StateSample(s["q"][k], s["v"][k], s["a"][k], s["tau"][k], s["tau_dot"][k],
                       bool(s["valid"][k]) if valid is None else valid)


def reference(s, k) -> ReferenceState:
    return ReferenceState(s["stamps"][k] * 1e-9, s["q"][k], s["v"][k], s["a"][k], s["contacts"][k])


def error_sample(s, k, act_obs=None) -> ErrorSample:
    return ErrorSample(s["phi"][k], s["observed"][k], s["gamma"][k],
                       np.ones(ROBOT.n_joints, bool) if act_obs is None else act_obs)


# ---------------------------------------------------------------------- pairing
def test_pairer_pairs_by_stamp_in_either_order_and_counts_unmatched():
    p = StampPairer(max_age_ns=10)
    assert p.add(STATE, 100, "s100") is None
    assert p.add(ERROR, 100, "e100") == (100, "s100", "e100")
    assert p.add(ERROR, 104, "e104") is None          # error first
    assert p.add(STATE, 104, "s104") == (104, "s104", "e104")
    assert p.add(STATE, 106, "s106") is None          # never gets an error
    assert p.add(STATE, 106, "again") is None
    assert p.counts["duplicate_stamps"] == 1
    assert p.add(ERROR, 120, "e120") is None          # 106 is now older than 120 - 10: evicted
    assert p.counts["unmatched_states"] == 1 and 106 not in p.pending[STATE]
    assert p.add(STATE, 105, "late") is None          # arrives already too late
    assert p.counts["unmatched_states"] == 2
    assert p.add(STATE, 120, "s120") == (120, "s120", "e120")
    assert p.pending == ({}, {})


def test_pairer_memory_is_bounded():
    p = StampPairer(max_age_ns=10**12, max_pending=5)
    for s in range(20):
        p.add(ERROR, s, s)
    assert len(p.pending[ERROR]) == 5 and p.counts["unmatched_errors"] == 15
    assert min(p.pending[ERROR]) == 15


# ---------------------------------------------------------------------- conversions
def test_model_error_sample_matches_by_name_and_rejects_bad_messages():
    rng = np.random.default_rng(1)
    phi, gamma = rng.normal(size=18), rng.normal(size=12)
    obs = rng.uniform(size=18) > 0.5
    msg = cv.model_error_msg(ROBOT, 5, "measured", phi, obs, gamma, np.ones(12, bool))
    # reorder every named array consistently: the result must not change
    pr, pa = rng.permutation(18), rng.permutation(12)
    msg.rbd_names = [msg.rbd_names[i] for i in pr]
    msg.rbd_error = [msg.rbd_error[i] for i in pr]
    msg.rbd_observed = [msg.rbd_observed[i] for i in pr]
    msg.actuation_names = [msg.actuation_names[i] for i in pa]
    msg.actuation_error = [msg.actuation_error[i] for i in pa]
    s = model_error_sample(ROBOT, msg)
    np.testing.assert_array_equal(s.rbd_error, phi)
    np.testing.assert_array_equal(s.rbd_observed, obs)
    np.testing.assert_array_equal(s.actuation_error, gamma)
    bad = cv.model_error_msg(ROBOT, 5, "measured", phi, obs, gamma, np.ones(12, bool))
    bad.rbd_error = [float("nan")] + list(bad.rbd_error[1:])
    with pytest.raises(ConversionError, match="non-finite"):
        model_error_sample(ROBOT, bad)
    bad = cv.model_error_msg(ROBOT, 5, "measured", phi, obs, gamma, np.ones(12, bool))
    bad.rbd_names = ["nope"] + list(bad.rbd_names[1:])
    with pytest.raises(ConversionError, match="names"):
        model_error_sample(ROBOT, bad)
    bad = cv.model_error_msg(ROBOT, 5, "measured", phi, obs, gamma, np.ones(12, bool))
    bad.actuation_names = list(bad.actuation_names[:-1]) + ["lf_haa_joint"]
    with pytest.raises(Exception, match="joint names"):
        model_error_sample(ROBOT, bad)
    bad = cv.model_error_msg(ROBOT, 5, "measured", phi, obs, gamma, np.ones(12, bool))
    bad.actuation_observed = [True] * 11
    with pytest.raises(ConversionError, match="observed"):
        model_error_sample(ROBOT, bad)


def test_robot_reference_arrays_by_name_and_rejects_nan():
    from ciml_msgs.msg import RobotReference

    s = stream(3)
    q, v, a = s["q"][1], s["v"][1], s["a"][1]
    v[:6] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    a[:6] = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    state = cv.robot_state_msg(ROBOT, 7, q, v, a, np.zeros(12), np.zeros(12), np.zeros(12), np.array([1, 0, 0, 1], bool),
                               True)
    perm = np.random.default_rng(2).permutation(12)
    msg = RobotReference(header=state.header, motion="trot_35", phase=0.3,
                         joint_names=[ROBOT.joint_names[i] for i in perm], base_pose=state.base_pose,
                         base_twist=state.base_twist, base_acceleration=state.base_acceleration,
                         position=q[7:][perm].tolist(), velocity=v[6:][perm].tolist(),
                         acceleration=a[6:][perm].tolist(), foot_names=list(ROBOT.foot_frames)[::-1],
                         in_contact=[True, False, False, True][::-1])
    q2, v2, a2, c2 = cv.robot_reference_arrays(ROBOT, msg)
    np.testing.assert_allclose(q2, q, atol=1e-12)
    np.testing.assert_array_equal(v2, v)
    np.testing.assert_array_equal(a2, a)
    np.testing.assert_array_equal(c2, [True, False, False, True])
    msg.velocity = [float("nan")] + list(msg.velocity[1:])
    with pytest.raises(ConversionError, match="non-finite"):
        cv.robot_reference_arrays(ROBOT, msg)


# ---------------------------------------------------------------------- learning
@pytest.mark.parametrize("calibration", [0, 40])
def test_online_learner_equals_offline_partial_fit_on_the_same_samples(calibration):
    n = 300
    s = stream(n)
    act_obs = np.ones((n, 12), bool)
    act_obs[50, :4] = False              # a partially observed Γ: those entries are not learned
    learner = OnlineLearner(ROBOT, ModelSet.for_robot(ROBOT, "lwpr"), calibration_samples=calibration, record_stamps=True)
    reasons = [learner.learn(int(s["stamps"][k]), state_sample(s, k), error_sample(s, k, act_obs[k])) for k in range(n)]
    assert reasons.count("invalid_samples") == int((~s["valid"]).sum())
    assert learner.n_learned == int(s["valid"].sum())
    np.testing.assert_array_equal(learner.learned_stamps, s["stamps"][s["valid"]])
    # offline: same valid samples, same order, through the documented batch API
    gamma = np.where(act_obs, s["gamma"], np.nan)
    offline = ModelSet.for_robot(ROBOT, "lwpr")
    if calibration:
        first = np.flatnonzero(s["valid"])[:calibration]
        offline.calibrate(s["X"][first], s["rbd"][first], s["rbd_observed"][first], gamma[first])
    offline.partial_fit(s["X"], s["rbd"], s["rbd_observed"], gamma, s["valid"], s["coupling"])
    on, off = learner.model_set.predict(s["X"]), offline.predict(s["X"])
    np.testing.assert_array_equal(on.rbd, off.rbd)
    np.testing.assert_array_equal(on.actuation, off.actuation)
    np.testing.assert_array_equal(learner.model_set.n_samples_, offline.n_samples_)
    assert learner.model_set.n_samples_[18] == learner.n_learned - 1   # the masked Γ entry was skipped
    # the comparison can fail: one sample fewer changes the model
    offline2 = ModelSet.for_robot(ROBOT, "lwpr")
    valid2 = s["valid"].copy()
    valid2[np.flatnonzero(valid2)[len(np.flatnonzero(valid2)) // 2]] = False
    if calibration:
        offline2.calibrate(s["X"][first], s["rbd"][first], s["rbd_observed"][first], gamma[first])
    offline2.partial_fit(s["X"], s["rbd"], s["rbd_observed"], gamma, valid2, s["coupling"])
    p2 = offline2.predict(s["X"])
    assert not np.array_equal(np.hstack([p2.rbd, p2.actuation]), np.hstack([off.rbd, off.actuation]))


def test_online_learner_rejects_out_of_order_and_unobserved_pairs():
    s = stream(5)
    learner = OnlineLearner(ROBOT, ModelSet.for_robot(ROBOT, "lwpr"))
    st = state_sample(s, 0, True)
    assert learner.learn(10, st, error_sample(s, 0)) is None
    assert learner.learn(10, st, error_sample(s, 0)) == "out_of_order_pairs"
    assert learner.learn(9, st, error_sample(s, 0)) == "out_of_order_pairs"
    none = ErrorSample(s["phi"][0], np.zeros(18, bool), s["gamma"][0], np.zeros(12, bool))
    assert learner.learn(11, st, none) == "invalid_samples"
    assert learner.n_learned == 1 and learner.counts == {"out_of_order_pairs": 2, "invalid_samples": 1}
    with pytest.raises(ModelSetError, match="lwpr"):
        OnlineLearner(ROBOT, ModelSet.for_robot(ROBOT, "sgpr"))


# ---------------------------------------------------------------------- snapshots
def _trained(n=120, seed=0):
    s = stream(n, seed)
    learner = OnlineLearner(ROBOT, ModelSet.for_robot(ROBOT, "lwpr"), record_stamps=True)
    for k in range(n):
        learner.learn(int(s["stamps"][k]), state_sample(s, k), error_sample(s, k))
    return learner, s


def test_snapshot_writer_numbers_links_prunes_and_round_trips(tmp_path):
    learner, s = _trained()
    writer = SnapshotWriter(str(tmp_path / "online"), keep=2)
    saved = [writer.write(learner.snapshot()) for _ in range(3)]
    assert [os.path.basename(x.model_dir) for x in saved] == ["snapshot-000001", "snapshot-000002", "snapshot-000003"]
    assert [n for n, _ in writer.snapshots()] == [2, 3]            # keep=2
    assert os.path.realpath(tmp_path / "online" / LATEST) == saved[-1].model_dir
    loaded = ModelSet.load(saved[-1].model_dir, ROBOT)
    np.testing.assert_array_equal(loaded.predict(s["X"]).rbd, learner.model_set.predict(s["X"]).rbd)
    stamps = np.load(os.path.join(saved[-1].model_dir, STAMPS_FILE), allow_pickle=False)
    np.testing.assert_array_equal(stamps, s["stamps"][s["valid"]])
    assert saved[-1].samples == learner.n_learned and len(saved[-1].checksum) == 64
    assert SnapshotWriter(str(tmp_path / "online")).seq == 3      # a restart continues the numbering


def test_snapshot_is_a_copy_unaffected_by_later_learning(tmp_path):
    learner, s = _trained()
    snap = learner.snapshot()
    before = snap.model_set.predict(s["X"]).rbd.copy()
    s2 = stream(60, seed=5)
    for k in range(60):
        learner.learn(int(s["stamps"][-1] + 4_000_000 * (k + 1)), state_sample(s2, k, True),
                      error_sample(s2, k))
    assert not np.array_equal(learner.model_set.predict(s["X"]).rbd, before)
    np.testing.assert_array_equal(snap.model_set.predict(s["X"]).rbd, before)


# ---------------------------------------------------------------------- serving
def test_served_model_predicts_like_predict_one_and_refuses_bad_files(tmp_path):
    learner, s = _trained()
    saved = SnapshotWriter(str(tmp_path)).write(learner.snapshot())
    served = load_served_model(ROBOT, saved.model_dir, saved.checksum)
    assert served.name == f"lwpr:{os.path.basename(saved.model_dir)}"
    k = 33
    reference_torque = ReferenceTorque(ROBOT)
    for ref in (reference(s, k - 1), reference(s, k)):
        pred = predict_at_reference(ROBOT, served, ref, reference_torque)
    # the model set at the reference's state and the torque it asks for, and its rate
    expected_torque = ReferenceTorque(ROBOT)
    for j in (k - 1, k):
        x = s["X"][j].copy()
        rbd = learner.model_set.predict_one(x)[0]   # Φ̃ does not read the torque inputs
        x[-24:-12], x[-12:] = expected_torque(reference(s, j), rbd)
    _, _, gamma, gamma_var = learner.model_set.predict_one(x)
    assert np.abs(x[-12:]).max() > 1.0                       # τ̇_ref
    # published in the contact-invariant coordinates of /model_error/measured: Φ̃' = J'⁻ᵀΦ̃ (eq. 8)
    np.testing.assert_allclose(s["basis"][k].T @ pred.rbd_error, rbd, rtol=1e-9, atol=1e-9)
    assert np.abs(rbd).max() > 1.0
    np.testing.assert_allclose(pred.actuation_error, gamma, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(pred.actuation_variance, gamma_var)
    assert pred.source == served.name and pred.fallback is None and pred.actuation_observed.all()
    with pytest.raises(ModelFileError, match="announced"):
        load_served_model(ROBOT, saved.model_dir, "0" * 64)
    npz = os.path.join(saved.model_dir, "model.npz")
    data = bytearray(open(npz, "rb").read())
    data[len(data) // 2] ^= 0xFF
    open(npz, "wb").write(bytes(data))
    with pytest.raises(ModelFileError, match="checksum"):
        load_served_model(ROBOT, saved.model_dir)


def test_nominal_when_no_model_or_non_finite_prediction(tmp_path):
    s = stream(3)
    pred = predict_at_reference(ROBOT, None, reference(s, 0))
    assert pred.source == NOMINAL and pred.fallback == "no_model"
    assert not pred.rbd_error.any() and not pred.rbd_observed.any() and not pred.actuation_observed.any()
    prior = ModelSet.for_robot(ROBOT, "lwpr").output_scale_ ** 2   # an unlearned set's prior variance
    np.testing.assert_array_equal(pred.rbd_variance[:6], prior[:6])
    np.testing.assert_array_equal(pred.actuation_variance, prior[-12:])
    np.testing.assert_allclose(pred.rbd_variance[6:], (0.05 * ROBOT.total_mass * 9.81 / 4) ** 2)
    learner, _ = _trained()
    saved = SnapshotWriter(str(tmp_path)).write(learner.snapshot())
    served = load_served_model(ROBOT, saved.model_dir)
    served.model_set.predict_part_one = lambda x, part: (np.full(18 if part == "rbd" else 12, np.nan), np.ones(18))
    pred = predict_at_reference(ROBOT, served, reference(s, 0))
    assert pred.fallback == "non_finite_prediction" and pred.source == NOMINAL
    assert np.all(np.isfinite(pred.rbd_error)) and not pred.rbd_error.any()
    np.testing.assert_array_equal(pred.rbd_variance, nominal_prediction(ROBOT).rbd_variance)


# ---------------------------------------------------------------------- worker
def test_latest_only_worker_skips_stale_items_and_reports_errors():
    gate = threading.Event()
    seen = []

    def fn(item):
        if item == "block":
            gate.wait(5)
        if item == "bad":
            raise ValueError("broken")
        seen.append(item)
        return item * 2 if isinstance(item, int) else item

    w = LatestOnlyWorker(fn)
    w.submit("block")
    time.sleep(0.1)
    assert w.busy
    assert not w.submit(1)
    assert w.submit(2)            # replaces 1, which never runs
    gate.set()
    deadline = time.monotonic() + 5
    while w.busy and time.monotonic() < deadline:
        time.sleep(0.01)
    w.submit("bad")
    w.close()
    results = w.drain()
    assert seen == ["block", 2]
    assert [r.value for r in results[:2]] == ["block", 4]
    assert results[2].error == "ValueError: broken" and results[2].value is None
