"""The per-dimension model set: observed mask, ε (eq. 17), the model file format."""
from __future__ import annotations

import copy
import json
import os
import shutil

import numpy as np
import pytest

from ciml_learning.core.dynamics import ReferenceState, ReferenceTorque, RigidBodyDynamics, selection_matrix
from ciml_learning.core.extraction import combined_error, learning_inputs
from ciml_learning.core.projection import contact_invariant_basis
from ciml_learning.core.robot import example_robot_data_dir, load_robot
from ciml_learning.learning.model_epsilon import EpsilonFunction, load_epsilon_function
from ciml_learning.learning.model_files import FORMAT_VERSION, MODEL_JSON, MODEL_NPZ, ModelFileError, model_checksum
from ciml_learning.learning.models import ModelSet, ModelSetError, rbd_output_names
from ciml_learning.learning.synthetic import fit_arguments as fit_args
from ciml_learning.learning.synthetic import relative_rmse, synthetic_training_set

ROBOT = load_robot()
SMALL_SGPR = {"n_inducing": 15, "n_hyper_samples": 200, "max_iters": 3}


@pytest.fixture(scope="module")
def data():
    return synthetic_training_set(ROBOT, 12_000, seed=0)


@pytest.fixture(scope="module")
def lwpr_set(data):
    return ModelSet.for_robot(ROBOT, "lwpr").fit(*fit_args(data))


@pytest.fixture(scope="module")
def sgpr_set(data):
    small = {k: v[:1000] for k, v in data.items()}
    return ModelSet.for_robot(ROBOT, "sgpr", {g: SMALL_SGPR for g in ("base", "leg", "actuation")}).fit(
        *fit_args(small))


def reference_at(robot=ROBOT, seed=0, t=0.0) -> ReferenceState:
    rng = np.random.default_rng(seed)
    q = robot.neutral_configuration()
    q[2] = 0.6
    q[7:] = robot.standing_joints + rng.uniform(-0.1, 0.1, robot.n_joints)
    return ReferenceState(t, q, 0.2 * rng.standard_normal(robot.nv), rng.standard_normal(robot.nv),
                          np.ones(robot.n_feet, bool))


def test_observed_mask_and_valid_flag_are_respected(data):
    """A leg joint's error is learned only where its leg swings and the sample is valid:
    unobserved entries and invalid samples hold garbage (1e3) that would ruin the fit if used."""
    corrupted = dict(data)
    rbd = np.where(data["generalized_observed"], data["generalized_error"], 1e3)
    act = data["actuation_error"].copy()
    rbd[~data["valid"]] = 1e3
    act[~data["valid"]] = -1e3
    coupling = data["leg_coupling"].copy()
    coupling[~data["valid"]] = np.nan
    corrupted["generalized_error"], corrupted["actuation_error"], corrupted["leg_coupling"] = rbd, act, coupling
    ms = ModelSet.for_robot(ROBOT, "lwpr").fit(*fit_args(corrupted))
    usable = data["generalized_observed"] & data["valid"][:, None]
    np.testing.assert_array_equal(ms.n_samples_[:18], usable.sum(axis=0))
    np.testing.assert_array_equal(ms.n_samples_[18:], data["valid"].sum())
    assert np.all(ms.n_samples_[6:18] < 0.5 * ms.n_samples_[0])  # leg joints: swing samples only
    test = synthetic_training_set(ROBOT, 4_000, seed=1)
    scores = relative_rmse(ms, test)
    assert scores["actuation_relative_rmse_max"] < 0.3, scores
    pred = ms.predict(test["inputs"], return_var=False)
    swing = test["generalized_observed"][:, 6:]
    leg_error = [np.sqrt(np.mean((pred.rbd[swing[:, j], 6 + j] - test["rbd_true"][swing[:, j], 6 + j]) ** 2))
                 for j in range(12)]
    # the leg joints' noise is ≈ 1–2 Nm (3 N on the foot entries); truths 2–3.5 Nm RMS. A joint's
    # error moves by ±0.2 Nm with the metric penalty (γ 1e-6 … 1e-3: max 1.92 … 2.15, median 1.16–1.21)
    assert np.max(leg_error) < 2.3 and np.median(leg_error) < 1.3, leg_error
    assert np.sqrt(np.mean((pred.rbd[:, 2] - test["rbd_true"][:, 2]) ** 2)) < 0.25 * 49.0  # payload weight
    # a leg that never swings (standing) keeps no model: zero error, prior variance
    standing = {k: v[:3000] for k, v in data.items()}
    obs = standing["generalized_observed"].copy()
    obs[:, 6:9] = False
    standing["generalized_observed"] = obs
    ms2 = ModelSet.for_robot(ROBOT, "lwpr").fit(*fit_args(standing))
    assert all(ms2.models_[i] is None for i in (6, 7, 8)) and ms2.models_[9] is not None
    pred = ms2.predict(test["inputs"][:10])
    np.testing.assert_array_equal(pred.rbd[:, 6:9], 0.0)
    np.testing.assert_allclose(pred.rbd_var[:, 6:9], np.tile(ms2.output_scale_[6:9] ** 2, (10, 1)))



def test_actuation_models_learn_where_the_torques_are_usable(data):
    """With effort_valid, Γ's models learn from its rows (here: also the contact changes, which
    are not valid) and the rigid-body models still from the valid rows only: garbage (±1e3) in
    the entries neither may use changes nothing. partial_fit takes the same rows."""
    X, R, M, A, V, C = fit_args(data)
    effort_valid = np.ones(len(X), bool)
    effort_valid[::7] = False
    assert (~V & effort_valid).sum() > 1000  # rows Γ gains
    rbd = np.where(M & V[:, None], R, 1e3)
    act = np.where(effort_valid[:, None], A, -1e3)
    ms = ModelSet.for_robot(ROBOT, "lwpr").fit(X, rbd, M, act, V, C, effort_valid=effort_valid)
    clean = ModelSet.for_robot(ROBOT, "lwpr").fit(X, R, M, A, V, C, effort_valid=effort_valid)
    np.testing.assert_array_equal(ms.n_samples_[:18], (M & V[:, None]).sum(axis=0))
    np.testing.assert_array_equal(ms.n_samples_[18:], effort_valid.sum())
    test = synthetic_training_set(ROBOT, 4_000, seed=1)
    pred, pred_clean = ms.predict(test["inputs"]), clean.predict(test["inputs"])
    np.testing.assert_array_equal(pred.rbd, pred_clean.rbd)
    np.testing.assert_array_equal(pred.actuation, pred_clean.actuation)
    assert relative_rmse(ms, test)["actuation_relative_rmse_max"] < 0.15
    online = ModelSet.for_robot(ROBOT, "lwpr")
    online.calibrate(X[:3000], rbd[:3000], M[:3000], act[:3000], V[:3000], effort_valid=effort_valid[:3000])
    online.partial_fit(X[:3000], rbd[:3000], M[:3000], act[:3000], V[:3000], C[:3000],
                       effort_valid=effort_valid[:3000])
    np.testing.assert_array_equal(online.n_samples_[:18], (M[:3000] & V[:3000, None]).sum(axis=0))
    np.testing.assert_array_equal(online.n_samples_[18:], effort_valid[:3000].sum())
    with pytest.raises(ModelSetError, match="effort_valid"):
        ms.fit(X, rbd, M, act, V, C, effort_valid=effort_valid[:10])


def test_stance_legs_learned_errors_are_added_back_to_the_base_wrench(data):
    """The measured base rows lack the stance legs' joint errors (C e, through the contact-
    invariant basis); with the leg coupling the set learns the true base wrench (payload,
    known), without it a gait-dependent leftover."""
    test = synthetic_training_set(ROBOT, 4_000, seed=1)
    errors = []
    for coupling in (data["leg_coupling"], None):
        args = list(fit_args(data))
        args[5] = coupling
        pred = ModelSet.for_robot(ROBOT, "lwpr").fit(*args).predict(test["inputs"], return_var=False)
        errors.append(np.sqrt(np.mean((pred.rbd[:, :6] - test["rbd_true"][:, :6]) ** 2, axis=0)))
    with_coupling, without = errors
    assert np.all(with_coupling[[0, 1, 3, 5]] < 0.6 * without[[0, 1, 3, 5]]), errors
    assert np.sqrt(np.mean(with_coupling ** 2)) < 0.7 * np.sqrt(np.mean(without ** 2)), errors


def test_base_wrench_targets_of_one_sample_equal_the_batch_rows(lwpr_set, data):
    """partial_fit_one's one-sample path (predict_one per stance leg) gives the batch's numbers."""
    X, rbd, observed, _gamma, _valid, C = fit_args(data, slice(0, 40))
    Xs = lwpr_set.standardize(X)
    batch = lwpr_set.base_wrench_targets(Xs, rbd, observed, C)
    one = np.array([lwpr_set.base_wrench_targets(Xs[k:k + 1], rbd[k:k + 1], observed[k:k + 1], C[k:k + 1])[0]
                    for k in range(len(X))])
    assert (~observed[:, 6:]).any() and np.abs(batch - rbd[:, :6]).max() > 0  # stance legs predicted
    np.testing.assert_array_equal(one, batch)


def test_online_partial_fit_matches_batch_and_snapshots(data, tmp_path):
    """partial_fit_one sample by sample == partial_fit on the batch; a snapshot saved while
    learning loads back to exactly that state."""
    n = 3_000
    part = {k: v[:n] for k, v in data.items()}
    a = ModelSet.for_robot(ROBOT, "lwpr")
    b = ModelSet.for_robot(ROBOT, "lwpr")
    a.partial_fit(*fit_args(part))
    snapshot_at = 2_000
    for k in range(n):
        if part["valid"][k]:
            b.partial_fit_one(part["inputs"][k], part["generalized_error"][k], part["generalized_observed"][k],
                              part["actuation_error"][k], part["leg_coupling"][k])
        if k == snapshot_at:
            b.save(str(tmp_path / "snap"))
            expected = b.predict(data["inputs"][-50:])
    np.testing.assert_array_equal(a.n_samples_, b.n_samples_)
    pa, pb = a.predict(data["inputs"][-200:]), b.predict(data["inputs"][-200:])
    np.testing.assert_array_equal(pa.rbd, pb.rbd)
    np.testing.assert_array_equal(pa.actuation_var, pb.actuation_var)
    snap = ModelSet.load(str(tmp_path / "snap"), ROBOT).predict(data["inputs"][-50:])
    np.testing.assert_array_equal(snap.rbd, expected.rbd)
    np.testing.assert_array_equal(snap.actuation, expected.actuation)
    # predict_one equals predict
    rbd, rbd_var, act, act_var = b.predict_one(data["inputs"][-1])
    np.testing.assert_allclose(rbd, pb.rbd[-1], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(act_var, pb.actuation_var[-1], rtol=1e-12)


def test_stacked_online_path_equals_the_per_dimension_path(data):
    """Online, each group's LWPR models are updated and predicted in one kernel call (LWPRStack);
    one model after the other gives the same model state and mean predictions to the bit, the same
    variances too (both square by multiplying) — through the stacks' growth (narrow fields: many are
    created), a model leaving its stack, and a copy taken while learning."""
    narrow = {"base": {"init_D": 20.0}, "leg": {"init_D": 200.0}, "actuation": {"init_D": 200.0}}
    stacked = ModelSet.for_robot(ROBOT, "lwpr", narrow)
    per_dim = ModelSet.for_robot(ROBOT, "lwpr", narrow)
    per_dim.lwpr_stacks = dict  # type: ignore[method-assign]  # never stacked: one model after the other
    X, rbd, observed, gamma, valid, C = fit_args(data, slice(0, 600))
    rng = np.random.default_rng(3)
    X = X + 0.3 * X.std(axis=0) * rng.standard_normal(X.shape)  # random inputs around the gait's
    copy_at, copied, grown = 300, None, False
    for k in np.flatnonzero(valid):
        for ms in (stacked, per_dim):
            ms.partial_fit_one(X[k], rbd[k], observed[k], gamma[k], C[k])
        for a, b in zip(stacked.predict_one(X[k]), per_dim.predict_one(X[k])):
            np.testing.assert_array_equal(a, b)
        if not grown and "leg" in stacked.lwpr_stacks():  # a model grown on its own leaves its stack
            grown = True
            legs = stacked.lwpr_stacks()["leg"]
            stacked.models_[6]._grow()
            per_dim.models_[6]._grow()
            assert not legs.intact and stacked.lwpr_stacks()["leg"] is not legs
        if k >= copy_at and copied is None:
            copied = copy.deepcopy(stacked)
            at_copy = copied.to_arrays()
    stacks = stacked.lwpr_stacks()
    assert grown and set(stacks) == {"base", "leg", "actuation"}
    assert all(st.models[0].rf_["c"].shape[0] > 16 for st in stacks.values())  # grew past the first capacity
    a, b = stacked.to_arrays(), per_dim.to_arrays()
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)
    np.testing.assert_array_equal(stacked.n_samples_, per_dim.n_samples_)
    assert copied is not None  # the copy owns its arrays: the original learned on without changing it
    for key, value in copied.to_arrays().items():
        np.testing.assert_array_equal(value, at_copy[key], err_msg=key)


def test_batch_only_learner_refuses_partial_fit(sgpr_set, data):
    with pytest.raises(ModelSetError, match="partial_fit"):
        sgpr_set.partial_fit_one(data["inputs"][0], data["generalized_error"][0], data["generalized_observed"][0],
                                 data["actuation_error"][0])


@pytest.mark.parametrize("which", ["lwpr", "sgpr"])
def test_save_load_identical_predictions(which, lwpr_set, sgpr_set, data, tmp_path):
    ms = lwpr_set if which == "lwpr" else sgpr_set
    ms.training_ = {"bags": ["a.mcap"], "samples": 12_000}
    out = str(tmp_path / "model")
    meta = ms.save(out)
    assert sorted(os.listdir(out)) == [MODEL_JSON, MODEL_NPZ]
    with open(os.path.join(out, MODEL_JSON)) as f:
        on_disk = json.load(f)
    assert on_disk["format_version"] == FORMAT_VERSION and on_disk["learner"] == which
    assert on_disk["kernel"] in ("gaussian_receptive_fields", "matern32_ard")
    assert on_disk["robot"]["joint_names"] == list(ROBOT.joint_names)
    assert on_disk["outputs"]["rbd"] == list(rbd_output_names(ROBOT))
    assert on_disk["training"]["bags"] == ["a.mcap"] and len(on_disk["npz"]["sha256"]) == 64
    assert meta == on_disk
    with np.load(os.path.join(out, MODEL_NPZ), allow_pickle=False) as npz:
        assert all(npz[k].dtype != object for k in npz.files)
    loaded = ModelSet.load(out, ROBOT)
    X = data["inputs"][-300:]
    p1, p2 = ms.predict(X), loaded.predict(X)
    for field in ("rbd", "rbd_var", "actuation", "actuation_var"):
        np.testing.assert_array_equal(getattr(p1, field), getattr(p2, field))


def _saved(ms, tmp_path, name="m") -> str:
    out = str(tmp_path / name)
    ms.save(out)
    return out


def one_line_error(model_dir, match, robot=ROBOT):
    with pytest.raises(ModelFileError, match=match) as info:
        ModelSet.load(model_dir, robot)
    assert "\n" not in str(info.value)


def test_tampered_truncated_and_wrong_version_files_are_refused(lwpr_set, tmp_path):
    good = _saved(lwpr_set, tmp_path, "good")
    npz_bytes = open(os.path.join(good, MODEL_NPZ), "rb").read()
    meta = json.load(open(os.path.join(good, MODEL_JSON)))

    def variant(name: str, npz: bytes = npz_bytes, meta_obj=None, meta_text: str | None = None) -> str:
        d = str(tmp_path / name)
        os.makedirs(d)
        with open(os.path.join(d, MODEL_NPZ), "wb") as f:
            f.write(npz)
        with open(os.path.join(d, MODEL_JSON), "w") as f:
            f.write(meta_text if meta_text is not None else json.dumps(meta_obj or meta))
        return d

    tampered = bytearray(npz_bytes)
    tampered[len(tampered) // 2] ^= 0xFF
    one_line_error(variant("tampered", bytes(tampered)), "checksum")
    one_line_error(variant("truncated_npz", npz_bytes[: len(npz_bytes) // 3]), "checksum")
    one_line_error(variant("truncated_json", meta_text=json.dumps(meta)[:200]), "not valid JSON")
    one_line_error(variant("v1", meta_obj={**meta, "format_version": 1}), "format_version 1")
    one_line_error(variant("learner", meta_obj={**meta, "learner": "GPy.core.GP"}), "unknown learner")
    # a consistent checksum does not make a malformed file acceptable
    import hashlib
    import io

    with np.load(io.BytesIO(npz_bytes), allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    arrays["dim00.rf.c"] = arrays["dim00.rf.c"][:, :3]
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    bad = buf.getvalue()
    def forge(blob: bytes) -> dict:
        info = {"sha256": hashlib.sha256(blob).hexdigest(), "bytes": len(blob)}
        m = {**meta, "npz": {"file": MODEL_NPZ, **info}, "manifest": {MODEL_NPZ: info}}
        return {**m, "checksum": model_checksum(m)}

    one_line_error(variant("malformed", bad, forge(bad)), "rf.c has shape")
    # pickled object arrays are never loaded
    arrays2 = dict(arrays)
    arrays2["input_mean"] = np.array([{"evil": 1}], dtype=object)
    buf = io.BytesIO()
    np.savez(buf, **arrays2)
    objs = buf.getvalue()
    one_line_error(variant("pickled", objs, forge(objs)), "not a readable npz|input_mean")
    # the description is covered too: reversed input names or a dimension switched off
    names = meta["inputs"]["names"]
    one_line_error(variant("names", meta_obj={**meta, "inputs": {**meta["inputs"], "names": names[::-1]}}),
                   "its own checksum")
    dims = [dict(d) for d in meta["dimensions"]]
    dims[0]["learned"] = False
    one_line_error(variant("unlearned", meta_obj={**meta, "dimensions": dims}), "its own checksum")
    shutil.rmtree(os.path.join(good))
    one_line_error(good, "not found")


def test_wrong_robot_is_refused(lwpr_set, tmp_path):
    out = _saved(lwpr_set, tmp_path)
    solo = load_robot(os.path.join(example_robot_data_dir(), "solo_description", "robots", "solo12.urdf"),
                      ["FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"])
    one_line_error(out, "different robot", robot=solo)
    with pytest.raises(ModelFileError, match="different robot"):
        load_epsilon_function(solo, out)


def test_model_set_works_for_another_robot():
    """Nothing assumes HyQ: a model set for solo12 trains, saves and predicts ε."""
    solo = load_robot(os.path.join(example_robot_data_dir(), "solo_description", "robots", "solo12.urdf"),
                      ["FL_FOOT", "FR_FOOT", "HL_FOOT", "HR_FOOT"])
    d = synthetic_training_set(solo, 2_000, seed=3)
    ms = ModelSet.for_robot(solo, "lwpr").fit(*fit_args(d))
    eps = EpsilonFunction(solo, ms)(reference_at(solo))
    assert eps.shape == (solo.nv,) and np.all(np.isfinite(eps))


def test_epsilon_is_eq17_at_the_reference(lwpr_set, tmp_path):
    out = _saved(lwpr_set, tmp_path)
    epsilon_fn = load_epsilon_function(ROBOT, out)
    ref = reference_at()
    q, v, a = ref.q, ref.v, ref.a
    reference_torque = ReferenceTorque(ROBOT)
    for k, t in enumerate((0.0, 0.004)):  # the second call has a torque rate
        ref.t, ref.a = t, a + k
        eps = epsilon_fn(ref)
        zeros = np.zeros(ROBOT.n_joints)
        rbd, _, _, _ = lwpr_set.predict_one(learning_inputs(q, v, ref.a, zeros, zeros)[0])
        # the actuation models see the torque the reference asks for (with the learned Φ̃) and its rate
        tau, tau_dot = reference_torque(ref, rbd)
        _, _, gamma, _ = lwpr_set.predict_one(learning_inputs(q, v, ref.a, tau, tau_dot)[0])
        basis = contact_invariant_basis(RigidBodyDynamics(ROBOT).foot_jacobians(q), ROBOT.leg_joints)
        S = selection_matrix(ROBOT)
        # the set learns Φ̃ = J'ᵀΦ̃' (eq. 8): with Φ̃' = J'⁻ᵀΦ̃, ε is eq. (17)
        phi = np.linalg.solve(basis.T, rbd)
        np.testing.assert_allclose(eps, combined_error(basis, phi, gamma, S), rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(eps, rbd - S.T @ gamma, rtol=1e-12, atol=1e-12)
    assert np.abs(tau_dot).max() > 1.0 and np.abs(eps).max() > 1.0  # the learned error is not zero
    ref.t = 0.008
    _, var = load_epsilon_function(ROBOT, out).epsilon(ref, return_var=True)
    assert np.all(var > 0)
    # NaN never reaches the controller
    ref.q = q.copy()
    ref.q[8] = np.nan
    np.testing.assert_array_equal(epsilon_fn(ref), np.zeros(ROBOT.nv))
    assert epsilon_fn.n_nonfinite == 1


def test_bad_inputs_raise_one_line_errors(lwpr_set, data):
    with pytest.raises(ModelSetError, match="shapes"):
        ModelSet.for_robot(ROBOT, "lwpr").fit(data["inputs"][:, :10], *fit_args(data)[1:])
    with pytest.raises(ModelSetError, match="non-finite"):
        lwpr_set.predict(np.full((1, 74), np.nan))
    with pytest.raises(ModelSetError, match="calibrate"):
        lwpr_set.calibrate(*fit_args(data)[:5])
    from ciml_learning.learning.learners import LearnerError

    with pytest.raises(LearnerError, match="unknown lwpr hyper-parameter"):
        ModelSet.for_robot(ROBOT, "lwpr", {"base": {"n_inducing": 5}})
    with pytest.raises(ModelSetError, match="unknown parameter groups"):
        ModelSet.for_robot(ROBOT, "lwpr", {"foot": {}})
