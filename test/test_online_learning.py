"""online_learner and model_server on the live graph (issue 6, items 6 and 7).

a. `ciml play` replays a synthetic bag into state_filter → error_extractor →
   online_learner; the learner's final snapshot equals offline ModelSet.partial_fit on the
   same samples (offline filter + extraction of the same bag, the stamps the learner
   reports having learned, in its order) to a tolerance justified below.
b. model_server: nominal without a model, hot swap on /model_update without a gap,
   a tampered snapshot refused while the old model keeps serving, NaN references rejected.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import time

import numpy as np
import pytest
from rosutil import BIN, Listener, start_node, stop
from synthetic import write_synthetic_bag

from ciml_learning.core.dynamics import ReferenceState, ReferenceTorque
from ciml_learning.core.extraction import learning_inputs
from ciml_learning.core.robot import load_robot
from ciml_learning.learning.model_files import read_metadata
from ciml_learning.learning.models import ModelSet
from ciml_learning.learning.serving import predict_at_reference, served_model
from ciml_learning.learning.snapshots import STAMPS_FILE
from ciml_learning.logs.pipeline import load_dataset

ROBOT = load_robot()
CALIBRATION = 0
"""The deployment default (default scaling). With calibration the RBD models of so short a
bag stay untrusted (zero), which would make the comparison void for them; the calibration
path is checked for exact equality in ciml_learning/test/test_online.py."""
RATE = 0.5
"""Replay at half speed: on the shared 2-core machine, five Python processes at 250 Hz
otherwise lose more best-effort sensor messages (each loss restarts the online filter's
31-sample warm-up). Samples lost upstream are simply not learned; the comparison below
is on the samples the learner reports having learned."""


def _ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _diag_values(listener: Listener, node_name: str) -> dict[str, str]:
    """Newest /diagnostics key/values of one node."""
    for arr in reversed(listener.messages["/diagnostics"]):
        for status in arr.status:
            if status.name.endswith(node_name):
                return {kv.key: kv.value for kv in status.values}
    return {}


def _offline_model(X, rbd, observed, gamma, coupling, valid, effort_valid, calibration: int) -> ModelSet:
    """What the online learner should have built: calibrate on the first samples, then
    partial_fit on all of them in order (the documented batch API)."""
    ms = ModelSet.for_robot(ROBOT, "lwpr")
    if calibration:
        c = slice(calibration)
        ms.calibrate(X[c], rbd[c], observed[c], gamma[c], valid[c], effort_valid[c])
    return ms.partial_fit(X, rbd, observed, gamma, valid, coupling, effort_valid)


def _both(pred) -> np.ndarray:
    return np.hstack([pred.rbd, pred.actuation])


@pytest.mark.ros
@pytest.mark.slow
def test_online_model_from_replay_matches_offline_partial_fit(tmp_path):
    from ciml_msgs.msg import LearningSample, ModelUpdate
    from diagnostic_msgs.msg import DiagnosticArray

    from ciml_learning.core import conversions as cv
    from ciml_learning.ros.ros_common import COMMAND_QOS

    bag = tmp_path / "bag"
    write_synthetic_bag(ROBOT, bag, seconds=4.0)
    offline = load_dataset(ROBOT, [str(bag)], progress=False)
    model_root = tmp_path / "online"
    listener = Listener({"/model_update": ModelUpdate, "/diagnostics": DiagnosticArray})
    nodes = [start_node("state_filter"), start_node("error_extractor"),
             start_node("online_learner", "-p", f"model_dir:={model_root}", "-p", "snapshot_period:=0.5",
                        "-p", "record_stamps:=true", "-p", f"calibration_samples:={CALIBRATION}",
                        # the synthetic bag's torques are not a robot's (nothing holds the trunk: base
                        # force errors to 1.8 m·g), beyond the learner's physical bounds at scale 1
                        "-p", "bound_scale:=5.0",
                        # every sample learned and every snapshot announced whole: the comparison is
                        # with an offline fit of the same samples (the snapshot gate is test_online's)
                        "-p", "validate_snapshots:=false")]
    try:
        # all three nodes up and discovered (imports and JIT loading take a while) before the replay
        assert listener.wait_for(lambda: listener.node.count_publishers("/model_update") >= 1
                                 and listener.node.count_subscribers("/filtered_state") >= 1
                                 and listener.node.count_subscribers("/model_error/learning_samples") >= 1
                                 and listener.node.count_subscribers("/joint_states") >= 1, timeout=40)
        time.sleep(1.0)
        subprocess.run([os.path.join(BIN, "ciml"), "play", "--bag", str(bag), "--rate", str(RATE)], check=True,
                       capture_output=True, timeout=60)

        # the last snapshot: announcements stop once nothing new is learned (period 0.5 s)
        ups = listener.messages["/model_update"]
        count, changed, deadline = -1, time.monotonic(), time.monotonic() + 30
        while time.monotonic() < deadline and not (ups and count == len(ups) and time.monotonic() - changed > 2.0):
            if len(ups) != count:
                count, changed = len(ups), time.monotonic()
            time.sleep(0.1)
        assert ups, "no /model_update after the replay"
        # bad inputs are rejected and counted (after the replay: they cannot affect the model)
        sample_pub = listener.node.create_publisher(LearningSample, "/model_error/learning_samples", COMMAND_QOS)
        listener.wait_for(lambda: sample_pub.get_subscription_count() >= 1, timeout=10)
        time.sleep(0.5)
        bad_state = cv.robot_state_msg(ROBOT, 99 * 10**9, offline.log.q[500], offline.log.v[500], offline.log.a[500],
                                       offline.log.tau[500], offline.log.tau_dot[500], offline.log.u[500],
                                       offline.log.contacts[500], True)
        bad_state.joint_names = ["not_a_joint"] + list(bad_state.joint_names[1:])
        error = cv.model_error_msg(ROBOT, 99 * 10**9, "measured", np.zeros(18), np.ones(18, bool),
                                   np.zeros(12), np.ones(12, bool))
        bad_error = cv.model_error_msg(ROBOT, 99 * 10**9, "measured", np.full(18, np.nan), np.ones(18, bool),
                                       np.zeros(12), np.ones(12, bool))
        good_state = cv.robot_state_msg(ROBOT, 99 * 10**9, offline.log.q[500], offline.log.v[500],
                                        offline.log.a[500], offline.log.tau[500], offline.log.tau_dot[500],
                                        offline.log.u[500], offline.log.contacts[500], True)
        sample_pub.publish(LearningSample(header=error.header, sequence=10**6, state=bad_state, error=error))
        sample_pub.publish(LearningSample(header=error.header, sequence=10**6 + 1, state=good_state, error=bad_error))
        assert listener.wait_for(lambda: int(_diag_values(listener, "online_learner").get("rejected_samples", 0)) >= 2,
                                 timeout=5), _diag_values(listener, "online_learner")
        diag = _diag_values(listener, "online_learner")
    finally:
        logs = [stop(p) for p in nodes]
        listener.close()
    update = listener.messages["/model_update"][-1]
    assert update.learner == "lwpr" and os.path.dirname(update.model_dir) == str(model_root), logs[2]
    assert read_metadata(update.model_dir)["checksum"] == update.checksum  # the whole-model checksum
    online = ModelSet.load(update.model_dir, ROBOT)
    stamps = np.load(os.path.join(update.model_dir, STAMPS_FILE), allow_pickle=False)
    assert len(stamps) == update.samples == int(diag["samples_learned"]) and np.all(np.diff(stamps) > 0)

    # the learned samples are the offline pipeline's valid samples (DDS may have dropped a few)
    t_off = np.round(offline.targets.t * 1e9).astype(np.int64)
    rows = np.searchsorted(t_off, stamps)
    assert np.all(rows < len(t_off)) and np.array_equal(t_off[rows], stamps), "learned a stamp not in the bag"
    tg = offline.targets
    assert (tg.valid | tg.effort_valid)[rows].all(), "learned a sample the offline pipeline marks invalid"
    # most of them: losses upstream (best-effort sensor topics) are tolerated, not hidden
    assert tg.valid[rows].sum() >= 0.5 * offline.n_valid, (len(rows), offline.n_valid, diag, logs[2][-3000:])
    assert (~tg.valid[rows]).sum() > 0.1 * len(rows)  # Γ's samples near contact changes (effort_sample_every)
    assert os.path.realpath(model_root / "latest") == update.model_dir

    X = learning_inputs(offline.log.q, offline.log.v, offline.log.a, offline.log.tau, offline.log.tau_dot)[rows]
    targets = (tg.generalized_error[rows], tg.generalized_observed[rows], tg.actuation_error[rows],
               tg.leg_coupling[rows], tg.valid[rows], tg.effort_valid[rows])
    reference = _offline_model(X, *targets, CALIBRATION)
    pred_on, pred_off = _both(online.predict(X)), _both(reference.predict(X))
    assert np.array_equal(online.n_samples_, reference.n_samples_)
    # Tolerance. Online, the samples come from the causal filter (state_filter) and eq. (11)
    # per message; offline from the zero-phase filter and batch extraction: the same numbers
    # up to float rounding (different summation order, ~1e-13 relative). LWPR is continuous
    # in its data except where a sample lands on a threshold (w_gen, w_prune), so
    # rounding-level input differences stay rounding-level in the model: perturbing every
    # input and target of this bag by 1e-7 (relative) moved predictions by ≤ 1.2e-5 · output
    # scale (sensitivity ~100), and replays measured ≤ 4e-14 · output scale. 1e-6 · output
    # scale (4e-5 N on a base force, 8e-6 Nm on an actuator) leaves orders of magnitude of
    # margin for rounding, and is >100× below what a different sample set gives (below).
    # The base wrench's narrow fields (D = 0.2) learn from targets that include the legs'
    # predictions: once in four fresh-clone runs a rounding-level difference flipped one of
    # their field decisions (20× the tolerance on base_fz, 6e-4 N); the base dimensions get
    # 100× the tolerance, still below what a different sample set gives.
    scale = online.output_scale_
    np.testing.assert_allclose(scale, reference.output_scale_, rtol=1e-12)  # same scaling
    tol = 1e-6 * scale
    err = np.abs(pred_on - pred_off)
    bound = tol * np.r_[np.full(6, 100.0), np.ones(len(tol) - 6)]
    assert np.all(err <= bound), ("prediction differs (× tolerance)", (err / tol).max(axis=0))
    assert np.all(np.mean(np.abs(pred_off) > 100 * tol, axis=0) > 0.5), "a dimension predicts ~nothing: comparison void"

    # the tolerance discriminates: skipping every 20th sample gives a clearly different model
    keep = np.ones(len(rows), bool)
    keep[::20] = False
    other = _offline_model(X[keep], *(z[keep] for z in targets), CALIBRATION)
    assert np.all(np.abs(_both(other.predict(X)) - pred_off).max(axis=0) > 100 * tol)  # ≥ bound


def _reference_msg(stamp_ns: int, q, v, a):
    from ciml_msgs.msg import RobotReference

    from ciml_learning.core import conversions as cv

    zeros = np.zeros(ROBOT.n_joints)
    state = cv.robot_state_msg(ROBOT, stamp_ns, q, v, a, zeros, zeros, zeros, np.ones(ROBOT.n_feet, bool), True)
    return RobotReference(header=state.header, motion="test", phase=0.0, joint_names=list(ROBOT.joint_names),
                          base_pose=state.base_pose, base_twist=state.base_twist,
                          base_acceleration=state.base_acceleration, position=list(state.position),
                          velocity=list(state.velocity), acceleration=list(state.acceleration),
                          foot_names=list(ROBOT.foot_frames), in_contact=[True] * ROBOT.n_feet)


def _reference_states(n: int):
    """References along a smooth joint motion around the standing posture (q, v, a rows)."""
    t = np.arange(n) / 50.0
    q = np.tile(ROBOT.neutral_configuration(), (n, 1))
    q[:, 2] = 0.6
    q[:, 7:] = ROBOT.standing_joints + 0.1 * np.sin(2 * np.pi * 0.7 * t[:, None] + np.arange(ROBOT.n_joints))
    v = np.zeros((n, ROBOT.nv))
    v[:, 6:] = 0.1 * 2 * np.pi * 0.7 * np.cos(2 * np.pi * 0.7 * t[:, None] + np.arange(ROBOT.n_joints))
    a = np.zeros((n, ROBOT.nv))
    return q, v, a


def _trained_model(model_dir) -> ModelSet:
    """A small LWPR model set learned from a known synthetic error (ciml_learning.learning.synthetic)."""
    from ciml_learning.learning.synthetic import fit_arguments, synthetic_training_set

    data = fit_arguments(synthetic_training_set(ROBOT, 1500, seed=3))
    ms = ModelSet.for_robot(ROBOT, "lwpr")
    ms.calibrate(*data[:5])
    ms.partial_fit(*data)
    ms.save(str(model_dir))
    return ms


@pytest.mark.ros
@pytest.mark.slow
def test_model_server_nominal_hot_swap_refusal_and_nan(tmp_path):
    from ciml_msgs.msg import ModelError, ModelUpdate, RobotReference
    from diagnostic_msgs.msg import DiagnosticArray

    from ciml_learning.ros.ros_common import COMMAND_QOS

    good = tmp_path / "model_a"
    ms = _trained_model(good)
    checksum = read_metadata(str(good))["checksum"]
    tampered = tmp_path / "model_b"
    shutil.copytree(good, tampered)
    npz = tampered / "model.npz"
    data = bytearray(npz.read_bytes())
    data[len(data) // 2] ^= 0x01
    npz.write_bytes(bytes(data))

    listener = Listener({"/model_error/predicted": ModelError, "/diagnostics": DiagnosticArray})
    ref_pub = listener.node.create_publisher(RobotReference, "/reference", COMMAND_QOS)
    upd_pub = listener.node.create_publisher(ModelUpdate, "/model_update", COMMAND_QOS)
    server = start_node("model_server")
    q, v, a = _reference_states(400)
    sent: dict[int, int] = {}          # stamp -> row of the reference

    def send(k: int, nan: bool = False) -> int:
        stamp = 1_000_000_000 + 20_000_000 * k
        vk = v[k].copy()
        if nan:
            vk[7] = np.nan
        ref_pub.publish(_reference_msg(stamp, q[k], vk, a[k]))
        if not nan:
            sent[stamp] = k
        return stamp

    def predictions():
        return {_ns(m.header.stamp): m for m in listener.messages["/model_error/predicted"]}

    def stream_until(k0: int, predicate, timeout: float) -> int:
        """Publish references at 50 Hz until predicate() holds; returns the next row."""
        k = k0
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and k < len(q):
            send(k)
            k += 1
            time.sleep(0.02)
            if predicate():
                return k
        raise AssertionError(f"timed out at reference {k}")

    try:
        assert listener.wait_for(lambda: ref_pub.get_subscription_count() >= 1
                                 and upd_pub.get_subscription_count() >= 1
                                 and listener.node.count_publishers("/model_error/predicted") >= 1, timeout=40)
        time.sleep(0.5)
        # 1. no model: nominal
        k = stream_until(0, lambda: len(predictions()) >= 5, timeout=15)
        first = listener.messages["/model_error/predicted"][0]
        assert first.source == "nominal" and not any(first.rbd_error) and not any(first.actuation_error)
        assert not any(first.rbd_observed) and not any(first.actuation_observed)
        assert min(first.rbd_variance) > 0 and min(first.actuation_variance) > 0
        # 2. hot swap to the saved model while references keep coming
        upd_pub.publish(ModelUpdate(model_dir=str(good), learner="lwpr", samples=1500, checksum=checksum))
        k = stream_until(k, lambda: any(m.source == "lwpr:model_a" for m in predictions().values()), timeout=15)
        k = stream_until(k, lambda: sum(m.source == "lwpr:model_a" for m in predictions().values()) >= 5, timeout=5)
        # 3. a tampered snapshot is refused; the old model keeps serving
        n_before = len(listener.messages["/model_error/predicted"])
        upd_pub.publish(ModelUpdate(model_dir=str(tampered), learner="lwpr", samples=1500, checksum=checksum))
        k = stream_until(k, lambda: int(_diag_values(listener, "model_server").get("refused_models", 0)) >= 1,
                         timeout=10)
        k = stream_until(k, lambda: len(listener.messages["/model_error/predicted"]) >= n_before + 30, timeout=5)
        # 4. a NaN reference produces no output and is counted
        nan_stamp = send(k, nan=True)
        k = stream_until(k + 1, lambda: int(_diag_values(listener, "model_server").get("rejected_references", 0)) >= 1,
                         timeout=10)
        last_sent = max(sent)
        listener.wait_for(lambda: last_sent in predictions(), timeout=5)
        diag = _diag_values(listener, "model_server")
    finally:
        log = stop(server)
        listener.close()

    preds = predictions()
    assert nan_stamp not in preds
    for m in preds.values():
        assert all(np.isfinite(m.rbd_error)) and all(np.isfinite(m.actuation_error))
    # no gap: every reference (after the first answered one: discovery) got an answer,
    # nominal before the swap, the model after it
    assert set(preds) == {s for s in sent if s >= min(preds)}, (len(preds), len(sent), log[-2000:])
    order = sorted(preds)
    sources = [preds[s].source for s in order]
    swap = sources.index("lwpr:model_a")
    assert set(sources[:swap]) == {"nominal"} and set(sources[swap:]) == {"lwpr:model_a"}, sources
    assert int(diag["refused_models"]) == 1 and int(diag["model_swaps"]) == 1, diag
    assert int(diag["rejected_references"]) == 1, diag
    # served values are serving.predict_at_reference at the reference, exactly (float64 over CDR),
    # with τ̇_ref over the stream of references the model served
    served = served_model(ROBOT, ms, "lwpr:model_a")
    reference_torque = ReferenceTorque(ROBOT)
    for s in order[swap:]:
        row = sent[s]
        ref = ReferenceState(s * 1e-9, q[row], v[row], a[row], np.ones(ROBOT.n_feet, bool))
        expected = predict_at_reference(ROBOT, served, ref, reference_torque)
        m = preds[s]
        for field in ("rbd_error", "rbd_variance", "actuation_error", "actuation_variance", "generalized_variance"):
            np.testing.assert_allclose(getattr(m, field), getattr(expected, field), rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(np.r_[m.rbd_observed, m.actuation_observed],
                                      np.r_[expected.rbd_observed, expected.actuation_observed])
    assert np.abs(np.r_[expected.rbd_error, expected.actuation_error]).max() > 1.0   # it predicts something


@pytest.mark.ros
def test_the_launch_model_serves_from_the_first_reference(tmp_path):
    """model_dir (the launch's `model`) is loaded before the server answers a reference: the first
    prediction is the model's, not the nominal model's while a worker loads it (the controller's
    rollback judged such a late model against the nominal start and rolled it back); a corrupt one
    is refused at start (counted) and the nominal model serves."""
    import random

    import rclpy
    from rclpy.parameter import Parameter

    from ciml_learning.nodes.model_server import ModelServerNode

    good = tmp_path / "model_a"
    _trained_model(good)
    bad = tmp_path / "model_b"
    shutil.copytree(good, bad)
    (bad / "model.npz").write_bytes(b"not a model")
    q, v, a = _reference_states(1)
    for model_dir, source in ((good, "lwpr:model_a"), (bad, "nominal")):
        ctx = rclpy.Context()
        rclpy.init(context=ctx, domain_id=random.SystemRandom().randint(1, 101))
        try:
            node = ModelServerNode(context=ctx, parameter_overrides=[Parameter("model_dir", value=str(model_dir))])
            out: list = []
            node.pub.publish = out.append
            node.on_reference(_reference_msg(1_000_000_000, q[0], v[0], a[0]))
            assert [m.source for m in out] == [source]
            assert node.health.counts["refused_models"] == (source == "nominal")
            assert node.health.counts["model_swaps"] == (source != "nominal")
            node.destroy_node()
        finally:
            rclpy.try_shutdown(context=ctx)
