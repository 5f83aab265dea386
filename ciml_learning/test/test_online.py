"""Pure helpers of the online_learner and model_server nodes (no rclpy.init, no DDS)."""
from __future__ import annotations

import copy
import json
import os
import threading
import time

import numpy as np
import pinocchio as pin
import pytest

from ciml_learning.core import conversions as cv
from ciml_learning.core.conversions import ConversionError
from ciml_learning.core.dynamics import ReferenceState, ReferenceTorque
from ciml_learning.core.errors import CimlError
from ciml_learning.core.extraction import dynamics_batch, learning_inputs
from ciml_learning.core.projection import contact_invariant_bases, generalized_rbd_error, leg_coupling
from ciml_learning.core.robot import load_robot
from ciml_learning.learning.learning_gate import AwaitReference
from ciml_learning.learning.model_files import ModelFileError, read_metadata, read_model_file
from ciml_learning.learning.models import ModelSet, ModelSetError
from ciml_learning.learning.online import (
    ErrorSample,
    OnlineLearner,
    SequenceGaps,
    StateSample,
    learning_sample,
)
from ciml_learning.learning.serving import (
    NOMINAL,
    SwapHold,
    load_served_model,
    nominal_prediction,
    predict_at_reference,
)
from ciml_learning.learning.snapshot_gate import (
    ACCEPTED,
    HELD_BACK,
    REFUSED_NOT_BETTER,
    REFUSED_TOO_FEW,
    ValidationConfig,
    validate,
)
from ciml_learning.learning.snapshots import LATEST, STAMPS_FILE, VALIDATION_FILE, SnapshotWriter
from ciml_learning.learning.workers import LatestOnlyWorker

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
                stamps=stamps, contacts=~swing, X=learning_inputs(q, v, a, tau, tau_dot), rbd=rbd,
                rbd_observed=rbd_observed, basis=basis, coupling=leg_coupling(basis, ROBOT.leg_joints))


def state_sample(s, k, valid=None) -> StateSample:
    valid = bool(s["valid"][k]) if valid is None else valid
    return StateSample(s["q"][k], s["v"][k], s["a"][k], s["tau"][k], s["tau_dot"][k], valid, valid)


def reference(s, k) -> ReferenceState:
    return ReferenceState(s["stamps"][k] * 1e-9, s["q"][k], s["v"][k], s["a"][k], s["contacts"][k])


def error_sample(s, k, act_obs=None) -> ErrorSample:
    return ErrorSample(s["phi"][k], s["observed"][k], s["gamma"][k],
                       np.ones(ROBOT.n_joints, bool) if act_obs is None else act_obs)


# ---------------------------------------------------------------------- conversions
def _learning_sample_msg(phi, obs, gamma, state=None):
    from ciml_msgs.msg import LearningSample

    error = cv.model_error_msg(ROBOT, 5, "measured", phi, obs, gamma, np.ones(12, bool))
    if state is None:
        s = stream(2)
        state = cv.robot_state_msg(ROBOT, 5, s["q"][1], s["v"][1], s["a"][1], s["tau"][1], s["tau_dot"][1],
                                   s["tau"][1], s["contacts"][1], True)
    return LearningSample(header=error.header, sequence=1, state=state, error=error)


def test_learning_sample_matches_by_name_and_rejects_bad_messages():
    rng = np.random.default_rng(1)
    phi, gamma = rng.normal(size=18), rng.normal(size=12)
    obs = rng.uniform(size=18) > 0.5
    msg = _learning_sample_msg(phi, obs, gamma)
    q, v, a, tau, tau_dot, _u, _c, valid, _effort_valid = cv.robot_state_arrays(ROBOT, msg.state)
    # reorder every named array consistently: the result must not change
    pr, pa = rng.permutation(18), rng.permutation(12)
    e = msg.error
    e.rbd_names = [e.rbd_names[i] for i in pr]
    e.rbd_error = [e.rbd_error[i] for i in pr]
    e.rbd_observed = [e.rbd_observed[i] for i in pr]
    e.actuation_names = [e.actuation_names[i] for i in pa]
    e.actuation_error = [e.actuation_error[i] for i in pa]
    stamp, st, s, q_ref, heard = learning_sample(ROBOT, msg)
    assert stamp == 5 and st.valid and valid and q_ref is None and not heard   # no reference attached
    np.testing.assert_array_equal(st.q, q)
    np.testing.assert_array_equal(st.tau_dot, tau_dot)
    np.testing.assert_array_equal(s.rbd_error, phi)
    np.testing.assert_array_equal(s.rbd_observed, obs)
    np.testing.assert_array_equal(s.actuation_error, gamma)
    bad = _learning_sample_msg(phi, obs, gamma)
    bad.error.rbd_error = [float("nan")] + list(bad.error.rbd_error[1:])
    with pytest.raises(ConversionError, match="non-finite"):
        learning_sample(ROBOT, bad)
    bad = _learning_sample_msg(phi, obs, gamma)
    bad.error.rbd_names = ["nope"] + list(bad.error.rbd_names[1:])
    with pytest.raises(ConversionError, match="names"):
        learning_sample(ROBOT, bad)
    bad = _learning_sample_msg(phi, obs, gamma)
    bad.error.actuation_names = list(bad.error.actuation_names[:-1]) + ["lf_haa_joint"]
    with pytest.raises(ConversionError, match="joint names"):
        learning_sample(ROBOT, bad)
    bad = _learning_sample_msg(phi, obs, gamma)
    bad.error.actuation_observed = [True] * 11
    with pytest.raises(ConversionError, match="observed"):
        learning_sample(ROBOT, bad)
    bad = _learning_sample_msg(phi, obs, gamma)
    bad.state.joint_names = ["not_a_joint"] + list(bad.state.joint_names[1:])
    with pytest.raises(CimlError, match="joint names"):  # what the node catches
        learning_sample(ROBOT, bad)
    # the extractor's /reference of the same instant, joints in another order: qᵈ in the robot's order
    with_ref = _learning_sample_msg(phi, obs, gamma)
    order = rng.permutation(12)
    r = with_ref.reference
    r.joint_names = [ROBOT.joint_names[i] for i in order]
    r.position = [float(q[7 + i]) + 0.01 for i in order]
    r.velocity = r.acceleration = [0.0] * 12
    r.base_pose.position.z, r.base_pose.orientation.w = 0.6, 1.0
    r.foot_names, r.in_contact = list(ROBOT.foot_frames), [True] * ROBOT.n_feet
    with_ref.references_heard = 7
    _stamp, _st, _s, q_ref, heard = learning_sample(ROBOT, with_ref)
    assert heard and q_ref[2] == 0.6
    np.testing.assert_allclose(q_ref[7:], q[7:] + 0.01)
    r.position = r.position[:-1]
    with pytest.raises(CimlError):                       # a malformed reference rejects the sample
        learning_sample(ROBOT, with_ref)


def test_robot_reference_arrays_by_name_and_rejects_nan():
    from ciml_msgs.msg import RobotReference

    s = stream(3)
    q, v, a = s["q"][1], s["v"][1], s["a"][1]
    v[:6] = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6]
    a[:6] = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    state = cv.robot_state_msg(ROBOT, 7, q, v, a, np.zeros(12), np.zeros(12), np.zeros(12),
                               np.array([1, 0, 0, 1], bool), True)
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
    learner = OnlineLearner(ROBOT, ModelSet.for_robot(ROBOT, "lwpr"), calibration_samples=calibration,
                            record_stamps=True)
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
    # near a contact change (not valid, effort_valid): Γ is learned, Φ̃' not, whatever its mask says
    near_change = StateSample(st.q, st.v, st.a, st.tau, st.tau_dot, False, True)
    before = learner.model_set.n_samples_.copy()
    assert learner.learn(12, near_change, error_sample(s, 1)) is None
    gained = learner.model_set.n_samples_ - before
    assert not gained[:18].any() and (gained[18:] == 1).all()
    neither = StateSample(st.q, st.v, st.a, st.tau, st.tau_dot, False, False)
    assert learner.learn(13, neither, error_sample(s, 2)) == "invalid_samples"
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
        rbd, rbd_var = learner.model_set.predict_one(x)[:2]   # Φ̃ does not read the torque inputs
        x[-24:-12], x[-12:] = expected_torque(reference(s, j), rbd)
    _, _, gamma, gamma_var = learner.model_set.predict_one(x)
    assert np.abs(x[-12:]).max() > 1.0                       # τ̇_ref
    # published in the contact-invariant coordinates of /model_error/measured: Φ̃' = J'⁻ᵀΦ̃ (eq. 8)
    np.testing.assert_allclose(s["basis"][k].T @ pred.rbd_error, rbd, rtol=1e-9, atol=1e-9)
    assert np.abs(rbd).max() > 1.0
    np.testing.assert_array_equal(pred.generalized_variance, rbd_var)  # Φ̃'s own, for the trust gate
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
def test_swap_hold_serves_the_first_model_at_once_and_each_later_one_after_the_hold():
    s = int(1e9)
    hold = SwapHold(6.0)
    assert hold.may_swap()                      # the nominal model at start is not held
    hold.swapped()                              # model A serves
    assert not hold.may_swap() and hold.remaining_s() == 6.0  # no reference served by it yet
    for t in (10 * s, 13 * s, 15 * s + s // 2):
        hold.reference(t)
        assert not hold.may_swap()
    assert hold.remaining_s() == 0.5            # what the model server waits for before it loads the next
    hold.reference(16 * s)
    assert hold.may_swap()                      # A has served 6 s of reference stamps
    hold.swapped()                              # B serves …
    hold.reference(17 * s)
    hold.rolled_back()                          # … and is rolled back: A serves again, 12 s
    assert hold.hold_s() == 12.0
    hold.reference(18 * s)
    hold.reference(29 * s)
    assert not hold.may_swap()
    hold.reference(30 * s)
    assert hold.may_swap()
    hold.swapped()                              # C, rolled back too: A serves 24 s
    hold.reference(31 * s)
    hold.rolled_back()
    assert hold.hold_s() == 24.0
    hold.reference(32 * s)
    hold.reference(2 * s)                       # stamps back in time (a reset): the hold restarts there
    hold.reference(25 * s)
    assert not hold.may_swap()
    hold.reference(26 * s)
    assert hold.may_swap()
    hold.swapped()                              # D serves its 6 s unharmed: back to 6 s
    hold.reference(27 * s)
    hold.reference(33 * s)
    assert hold.may_swap() and hold.hold_s() == 6.0 and hold.backoff == 0
    for _ in range(10):
        hold.swapped()
        hold.rolled_back()
    assert hold.hold_s() == 6.0 * 2 ** SwapHold.MAX_BACKOFF
    no_hold = SwapHold(0.0)
    no_hold.swapped()
    assert no_hold.may_swap()


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


# ---------------------------------------------------------------------- safety: bounds, gate, refusal
def test_physical_bounds_come_from_the_robot_description():
    from ciml_learning.core.physical_bounds import physical_bounds

    b = physical_bounds(ROBOT)
    mg = ROBOT.total_mass * 9.81
    assert b.weight == pytest.approx(mg) and 800 < mg < 900          # HyQ: ~87 kg
    assert 0.5 < b.standing_height < 0.7 and 0.5 < b.leg_span < 1.0  # m
    np.testing.assert_allclose(b.rbd_error[:3], mg)
    np.testing.assert_allclose(b.rbd_error[3:6], mg * b.leg_span)
    np.testing.assert_allclose(b.rbd_error[6:], mg)
    np.testing.assert_array_equal(b.actuation_error, ROBOT.torque_limits)
    np.testing.assert_array_equal(b.generalized[6:], ROBOT.torque_limits)
    assert b.rbd_violation(np.zeros(18)) is None
    bad = np.zeros(18)
    bad[2] = 1.01 * mg
    assert b.rbd_violation(bad).startswith("base_fz")
    assert b.actuation_violation(np.full(12, np.nan)) is not None      # NaN is never within bounds


def _gate_stream(n: int):
    """A robot standing and tracking its reference (the standing pose), 4 ms apart."""
    q = ROBOT.neutral_configuration().copy()
    q[2] = 0.6
    q[7:] = ROBOT.standing_joints
    return q, (np.arange(n) * 4_000_000 + 1_000_000_000).astype(np.int64)


def test_learning_gate_pauses_on_a_fall_and_resumes_after_recovery():
    from ciml_learning.learning.learning_gate import FALL, HOLD, GateConfig, LearningGate

    q, stamps = _gate_stream(1000)
    gate = LearningGate(ROBOT, GateConfig(resume_after=0.5))
    zeros_r, zeros_a = np.zeros(18), np.zeros(12)
    assert gate.check(stamps[0], q, zeros_r, zeros_a) is None and not gate.paused
    fallen = q.copy()
    fallen[2] = 0.2                                                    # the trunk on the ground
    assert gate.check(stamps[1], fallen, zeros_r, zeros_a) == FALL and gate.paused
    assert "base height 0.200 m" in gate.reason
    tipped = q.copy()
    tipped[3:7] = pin.Quaternion(pin.rpy.rpyToMatrix(0.8, 0.0, 0.0)).coeffs()
    assert gate.check(stamps[2], tipped, zeros_r, zeros_a) == FALL and "tilted 46°" in gate.reason
    # up again: still paused until the checks have passed for resume_after (0.5 s = 125 samples)
    results = [gate.check(s, q, zeros_r, zeros_a) for s in stamps[3:200]]
    first_learned = results.index(None)
    assert set(results[:first_learned]) == {HOLD} and not gate.paused
    assert (stamps[3 + first_learned] - stamps[2]) * 1e-9 == pytest.approx(0.5, abs=0.005)
    assert all(r is None for r in results[first_learned:])
    assert gate.counts[FALL] == 2 and gate.counts["resumed"] == 1


def test_learning_gate_checks_tracking_against_the_reference_of_the_same_stamp():
    from ciml_learning.core.pairing import ReferenceHistory
    from ciml_learning.learning.learning_gate import NO_REFERENCE, TRACKING, GateConfig, LearningGate

    q, stamps = _gate_stream(10)
    zeros_r, zeros_a = np.zeros(18), np.zeros(12)
    # no reference ever: a replayed log is learned (tracking unchecked) unless required
    assert LearningGate(ROBOT).check(stamps[0], q, zeros_r, zeros_a) is None
    assert LearningGate(ROBOT, GateConfig(require_reference=True)).check(stamps[0], q, zeros_r, zeros_a) == NO_REFERENCE
    # the extractor's history: the reference of a stamp is the nearest within max_reference_age
    references = ReferenceHistory(max_age_ns=20_000_000)
    for k, s in enumerate(stamps):
        references.add(s, k)
    assert references.at(stamps[3] + 1_000_000) == 3 and references.at(stamps[3] + 3_000_000) == 4
    assert references.at(stamps[-1] + 21_000_000) is None and references.heard == len(stamps)
    references.add(stamps[0], "restarted")                            # a stamp going back: a new stream
    assert references.at(stamps[-1]) is None and references.at(stamps[0]) == "restarted"
    gate = LearningGate(ROBOT, GateConfig(resume_after=0.0))
    assert gate.check(stamps[3], q, zeros_r, zeros_a, q, True) is None
    off = q.copy()
    off[0] += 0.3                                                     # 0.3 m away from the reference
    assert gate.check(stamps[4], off, zeros_r, zeros_a, q, True) == TRACKING and "base position 0.300 m" in gate.reason
    bent = q.copy()
    bent[7:] += 0.5
    assert gate.check(stamps[5], bent, zeros_r, zeros_a, q, True) == TRACKING and "RMS joint" in gate.reason
    assert gate.check(stamps[6], q, zeros_r, zeros_a, q, True) is None   # resume_after 0: at once
    # references heard, none near this stamp: paused (the reference stream stopped)
    assert gate.check(stamps[7], q, zeros_r, zeros_a, None, True) == NO_REFERENCE


def test_online_learner_does_not_learn_a_fall_or_targets_beyond_physics():
    from ciml_learning.learning.learning_gate import FALL, TARGET, LearningGate

    s = stream(200)
    mg = ROBOT.total_mass * 9.81

    def run(gate):
        learner = OnlineLearner(ROBOT, ModelSet.for_robot(ROBOT, "lwpr"), gate=gate)
        for k in range(50):
            learner.learn(int(s["stamps"][k]), state_sample(s, k, True), error_sample(s, k))
        # a falling state stream: the base sinks to the ground, the "error" grows past the
        # robot's weight (the ground, not the model, holds the trunk), then it lies there
        for k in range(50, 150):
            st = state_sample(s, k, True)
            st.q = st.q.copy()
            st.q[2] = max(0.6 - 0.01 * (k - 50), 0.15)
            err = error_sample(s, k)
            err.rbd_error = err.rbd_error.copy()
            err.rbd_error[2] = min(20.0 * (k - 50) ** 2, 3000.0)
            learner.learn(int(s["stamps"][k]), st, err)
        return learner

    gate = LearningGate(ROBOT)
    learner = run(gate)
    assert learner.n_learned == 50 + 7 and len(learner.probe_inputs) == 57   # 20 k² ≤ m·g for k ≤ 6
    # then paused: the target beyond m·g (k = 7…29), a fall from k = 30 (z = 0.30 m < 0.5 × 0.612 m)
    assert learner.counts[TARGET] == 23 and learner.counts[FALL] == 70
    assert gate.paused and gate.reason.startswith("fall: base height")
    base_fz = learner.model_set.predict(s["X"]).rbd[:, 2]
    assert np.abs(base_fz).max() < mg
    # the same stream without the gate learns the fall: a base force error beyond the weight
    ungated = run(None)
    assert ungated.n_learned == 150 and np.abs(ungated.model_set.predict(s["X"]).rbd[:, 2]).max() > mg


def test_model_server_refuses_unannounced_checksums_and_models_beyond_physical_bounds(tmp_path):
    from ciml_learning.learning.model_files import read_metadata
    from ciml_learning.learning.snapshots import PROBE_FILE

    learner, s = _trained()
    saved = SnapshotWriter(str(tmp_path / "online")).write(learner.snapshot())
    meta = read_metadata(saved.model_dir)
    assert saved.checksum == meta["checksum"] and PROBE_FILE in meta["manifest"]
    probes = np.load(os.path.join(saved.model_dir, PROBE_FILE), allow_pickle=False)
    assert probes.shape == (64, s["X"].shape[1])
    assert all(any(np.array_equal(p, x) for x in s["X"]) for p in probes)   # the learned inputs themselves
    load_served_model(ROBOT, saved.model_dir, saved.checksum)              # announced with its checksum: served
    load_served_model(ROBOT, saved.model_dir)                               # a configured model_dir: its own checksum
    with pytest.raises(ModelFileError, match="without a checksum"):
        load_served_model(ROBOT, saved.model_dir, "")
    # poisoned: the same model scaled ×1e6, saved properly (valid checksum) and announced
    poisoned = learner.snapshot().model_set
    poisoned.output_scale_ = poisoned.output_scale_ * 1e6
    meta_p = poisoned.save(str(tmp_path / "poisoned"), extra_files={
        PROBE_FILE: open(os.path.join(saved.model_dir, PROBE_FILE), "rb").read()})
    with pytest.raises(ModelFileError, match="beyond physical bounds"):
        load_served_model(ROBOT, str(tmp_path / "poisoned"), meta_p["checksum"])
    # without its probe file, the set's input mean and the standing posture still catch it
    poisoned.save(str(tmp_path / "poisoned2"))
    with pytest.raises(ModelFileError, match="beyond physical bounds"):
        load_served_model(ROBOT, str(tmp_path / "poisoned2"))


# ---------------------------------------------------------------------- the snapshot gate
GATE = ValidationConfig(block=0.2, every=5, window=800, min_learned=1000, min_heldout=100, margin=0.25)


def _learned_with_hold_back(n: int, config: ValidationConfig = GATE):
    s = stream(n, seed=3)
    learner = OnlineLearner(ROBOT, ModelSet.for_robot(ROBOT, "lwpr"), validation=config)
    reasons = [learner.learn(int(s["stamps"][k]), state_sample(s, k), error_sample(s, k)) for k in range(n)]
    return learner, s, reasons


def test_held_back_samples_are_whole_blocks_of_stamps_and_never_learned():
    learner, s, reasons = _learned_with_hold_back(1500)
    held = np.array([r == HELD_BACK for r in reasons])
    expected = np.array([GATE.held_back(t) for t in s["stamps"]]) & s["valid"]
    np.testing.assert_array_equal(held, expected)
    assert 0.15 < held.sum() / s["valid"].sum() < 0.25                   # one block in 5
    assert learner.n_learned == int(s["valid"].sum() - held.sum())
    assert learner.heldout.size == min(int(held.sum()), GATE.window)
    # whole blocks: the held-back stamps change state at most twice per 0.2 s × 5 of stream
    flips = np.count_nonzero(np.diff(expected[s["valid"]].astype(int)))
    assert flips <= 2 * (1500 / 250) / (GATE.block * GATE.every) + 2


def test_snapshot_gate_serves_a_model_better_than_nominal_and_refuses_a_worse_one():
    learner, s, _ = _learned_with_hold_back(6000)
    snap = learner.snapshot()
    good = validate(snap.model_set, snap.heldout, snap.samples, GATE)
    assert good.decision == ACCEPTED
    act = slice(ROBOT.nv, None)
    # Γ = −3 q̇ − 0.01 τ̇ + noise is learnable: every actuation output is served and explains most of the error
    assert good.accepted[act].all()
    assert np.all(good.mse_model[act] < 0.3 * good.mse_nominal[act])
    # a well-formed, finite, bounded model that predicts the error with the wrong sign is worse than nominal
    bad = copy.deepcopy(snap.model_set)
    bad.output_scale_ = -bad.output_scale_
    worse = validate(bad, snap.heldout, snap.samples, GATE)
    assert worse.decision == REFUSED_NOT_BETTER and not worse.accepted.any()
    assert np.all(worse.mse_model[act] > worse.mse_nominal[act])
    # too early: fewer samples learned than min_learned
    early = validate(snap.model_set, snap.heldout, 999, GATE)
    assert early.decision == REFUSED_TOO_FEW and not early.accepted.any()


def test_snapshot_writer_writes_only_accepted_snapshots_with_their_accepted_outputs(tmp_path):
    learner, s, _ = _learned_with_hold_back(6000)
    writer = SnapshotWriter(str(tmp_path / "online"), validation=GATE)
    snap = learner.snapshot()
    bad = copy.deepcopy(snap)
    bad.model_set.output_scale_ = -bad.model_set.output_scale_
    refused = writer.write(bad)
    assert refused.model_dir == "" and refused.validation.decision == REFUSED_NOT_BETTER
    assert writer.snapshots() == []                                    # nothing written
    saved = writer.write(snap)
    assert saved.validation.served and saved.model_dir
    served = load_served_model(ROBOT, saved.model_dir, saved.checksum)  # the decision is in the checksum
    kept = np.array([m is not None for m in served.model_set.models_])
    np.testing.assert_array_equal(kept, saved.validation.accepted)
    assert not saved.validation.accepted.all()                          # e.g. outputs never observed enough
    meta = read_metadata(saved.model_dir)
    assert VALIDATION_FILE in meta["manifest"]
    record = json.loads(read_model_file(saved.model_dir, meta, VALIDATION_FILE))
    assert record["decision"] == ACCEPTED
    assert [o["accepted"] for o in record["outputs"].values()] == saved.validation.accepted.tolist()


def test_lost_samples_are_counted_from_sequence_gaps():
    lost = SequenceGaps()
    for k in [1, 2, 3, 6, 7, 8, 10]:          # 4 and 5 missing, then 9
        lost.add(k)
    assert lost.lost == 3
    lost.add(1)                               # a restarted extractor is not a loss
    lost.add(2)
    assert lost.lost == 3


def test_pairs_wait_for_the_reference_of_their_stamp_in_order():
    ms = 1_000_000
    wait = AwaitReference(tolerance_ns=20 * ms, max_wait_ns=500 * ms)
    wait.push(100 * ms, "sample")
    assert [p[0] // ms for p in wait.ready(None)] == [100]               # no reference stream: at once
    for s in (104, 108, 112):
        wait.push(s * ms, "sample")
    assert wait.ready(50 * ms) == []                                     # references behind: wait
    assert [p[0] // ms for p in wait.ready(90 * ms)] == [104, 108]        # within 20 ms of the newest reference
    assert [p[0] // ms for p in wait.ready(112 * ms)] == [112]
    wait.push(120 * ms, "sample")
    wait.push(700 * ms, "sample")                                      # the reference stream died: 120 waited 580 ms
    assert [p[0] // ms for p in wait.ready(112 * ms)] == [120]
    assert len(wait.pending) == 1


def test_a_serialized_reference_is_placed_by_its_stamp_without_decoding():
    """error_extractor keeps /reference serialized (conversions.serialized_stamp_ns) and decodes only
    the one sent with a learning sample: the stamp read from the CDR bytes is the header's, in either
    byte order, and too few bytes are a ConversionError."""
    from ciml_msgs.msg import RobotReference
    from rclpy.serialization import serialize_message

    msg = RobotReference(joint_names=list(ROBOT.joint_names), position=[0.1] * 12)
    msg.header.stamp.sec, msg.header.stamp.nanosec = 1_795_962_576, 143_506_362
    data = serialize_message(msg)
    assert cv.serialized_stamp_ns(data) == 1_795_962_576_143_506_362
    big_endian = b"\x00\x00\x00\x00" + (-2).to_bytes(4, "big", signed=True) + (7).to_bytes(4, "big")
    assert cv.serialized_stamp_ns(big_endian) == -2_000_000_000 + 7
    with pytest.raises(ConversionError):
        cv.serialized_stamp_ns(data[:10])
