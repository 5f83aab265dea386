"""The learners (LWPR, sparse GP) on data with a known answer, and their one contract."""
from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from ciml_learning.learning.learners import LEARNERS, LWPR, LearnerError, SparseGPR, learner_class
from ciml_learning.learning.learners.sgpr import kmeans, matern32
from ciml_learning.learning.synthetic import cross_function

CROSS = dict(init_D=50.0, init_alpha=250.0, w_gen=0.2)  # the reference library's cross-function setup


def grid41() -> np.ndarray:
    g = np.linspace(-1, 1, 41)
    return np.array(np.meshgrid(g, g)).reshape(2, -1).T


def cross_data(n: int, seed: int, low=(-1.0, -1.0), high=(1.0, 1.0)):
    rng = np.random.default_rng(seed)
    X = rng.uniform(low, high, (n, 2))
    return X, cross_function(X) + 0.1 * rng.standard_normal(n)


def friction_data(n: int, seed: int, freq=(0.5, 2.0), amp=(0.1, 0.5)):
    """A joint's (q, q̇, q̈) along sinusoidal motions of random frequency/amplitude and the
    known actuation error of viscous plus smooth Coulomb friction, Γ = −(3 q̇ + 4 tanh(q̇/0.2)) [Nm],
    measured with 0.5 Nm noise."""
    rng = np.random.default_rng(seed)
    segments = []
    while sum(len(s) for s in segments) < n:
        w = 2 * np.pi * rng.uniform(*freq)
        a = rng.uniform(*amp)
        q0 = rng.uniform(-0.3, 0.3)
        t = np.arange(500) / 250.0 + rng.uniform(0, 10)
        segments.append(np.stack([q0 + a * np.sin(w * t), a * w * np.cos(w * t), -a * w * w * np.sin(w * t)], 1))
    X = np.vstack(segments)[:n]
    f = -(3.0 * X[:, 1] + 4.0 * np.tanh(X[:, 1] / 0.2))
    return X, f, f + 0.5 * rng.standard_normal(n)


def relative_rmse(pred: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean((pred - truth) ** 2)) / np.sqrt(np.mean(truth ** 2)))


# ------------------------------------------------------------------------------ LWPR
def test_lwpr_cross_function_nmse_below_005():
    """The classic 2-D cross function, 20,000 noisy samples (σ = 0.1): nMSE on the 41×41 grid
    below 0.05 (reference C library: ≈ 0.022 with ~55 fields)."""
    X, y = cross_data(20_000, seed=0)
    model = LWPR(**CROSS).fit(X, y)
    G = grid41()
    f = cross_function(G)
    nmse = np.mean((model.predict(G) - f) ** 2) / np.var(f)
    assert nmse < 0.05, nmse
    assert 20 <= model.n_receptive_fields <= 150, model.n_receptive_fields
    # the metric adapted: D of the fields moved away from the initial 50·I
    D = model.distance_metrics()
    assert np.max(np.abs(D - 50.0 * np.eye(2))) > 5.0


def test_lwpr_fields_where_data_arrive_and_uncertainty_grows_away():
    """Trained on the left half only: every field centre lies in the left half; on the
    right, far from the data, the mean returns to zero and the std grows."""
    X, y = cross_data(5_000, seed=1, low=(-1.0, -1.0), high=(0.0, 1.0))
    model = LWPR(**CROSS).fit(X, y)
    centres = model.receptive_field_centers()
    assert len(centres) > 5
    assert np.all(centres[:, 0] <= 0.0 + 1e-12)
    # new data on the right half: fields are added there
    X2, y2 = cross_data(2_000, seed=2, low=(0.5, -1.0), high=(1.0, 1.0))
    before = model.n_receptive_fields
    model.partial_fit(X2, y2)
    new = model.receptive_field_centers()[before:]
    assert len(new) > 0 and np.all(new[:, 0] >= 0.5)
    # uncertainty: at the data vs. progressively further away (x2 = 0 line, x1 beyond the data)
    model = LWPR(**CROSS).fit(X, y)
    probe = np.array([[-0.5, -0.5], [0.2, -0.5], [0.5, -0.5], [3.0, -0.5], [30.0, -0.5]])
    mean, std = model.predict(probe, return_std=True)
    assert std[0] < std[1] < std[2]                   # grows from the data to its edge and beyond
    assert std[0] < 0.5 * std[3]
    assert std[3] == pytest.approx(std[4], rel=1e-3)  # the prior: bounded, not diverging
    assert abs(mean[4]) < 1e-9                        # zero (the nominal model) far away
    assert std[4] == pytest.approx(np.sqrt(np.mean(y ** 2)), rel=1e-6)


def test_lwpr_partial_fit_equals_fit_and_single_updates():
    X, y = cross_data(3_000, seed=3)
    a = LWPR(**CROSS).fit(X, y)
    b = LWPR(**CROSS)
    for chunk in np.array_split(np.arange(len(X)), 7):
        assert b.partial_fit(X[chunk], y[chunk]) is b
    c = LWPR(**CROSS)
    for k in range(len(X)):
        c.update(X[k], y[k])
    G = grid41()
    assert a.n_receptive_fields == b.n_receptive_fields == c.n_receptive_fields
    np.testing.assert_array_equal(a.predict(G), b.predict(G))
    np.testing.assert_array_equal(a.predict(G), c.predict(G))


def test_lwpr_capacity_limit_and_pruning():
    X, y = cross_data(4_000, seed=4)
    capped = LWPR(**{**CROSS, "max_rfs": 10}).fit(X, y)
    assert capped.n_receptive_fields == 10
    assert np.all(np.isfinite(capped.predict(grid41())))
    # overlapping fields get pruned with a low prune threshold
    pruned = LWPR(**{**CROSS, "w_prune": 0.5}).fit(X, y)
    assert pruned.n_pruned_ > 0


def test_lwpr_meta_learning_and_diagonal_metric_work():
    X, y = cross_data(20_000, seed=5)
    G = grid41()
    f = cross_function(G)
    for extra in ({"meta": True}, {"diag_only": True}):
        model = LWPR(**CROSS, **extra).fit(X, y)
        nmse = np.mean((model.predict(G) - f) ** 2) / np.var(f)
        assert nmse < 0.06, (extra, nmse)
    assert LWPR(**CROSS, diag_only=True).fit(X[:500], y[:500]).rf_["M"].shape[1] == 2  # packed diagonal


def test_lwpr_state_round_trip_is_exact():
    X, y = cross_data(3_000, seed=6)
    model = LWPR(**CROSS, meta=True).fit(X, y)
    clone = LWPR.from_state(model.get_params(), model.get_state())
    G = grid41()
    m1, s1 = model.predict(G, return_std=True)
    m2, s2 = clone.predict(G, return_std=True)
    np.testing.assert_array_equal(m1, m2)
    np.testing.assert_array_equal(s1, s2)
    # and it keeps learning identically
    X2, y2 = cross_data(500, seed=7)
    model.partial_fit(X2, y2)
    clone.partial_fit(X2, y2)
    np.testing.assert_array_equal(model.predict(G), clone.predict(G))


# ------------------------------------------------------------------------------ sparse GP
def test_matern32_matches_gpy():
    import GPy

    rng = np.random.default_rng(0)
    X, Z = rng.normal(size=(40, 5)), rng.normal(size=(15, 5))
    ls = rng.uniform(0.5, 3.0, 5)
    k = GPy.kern.Matern32(5, variance=2.3, lengthscale=ls, ARD=True)
    np.testing.assert_allclose(matern32(X, Z, 2.3, ls), k.K(X, Z), rtol=1e-10, atol=1e-12)


def test_sgpr_posterior_matches_gpy_vardtc():
    """With the hyper-parameters held at their initial values (max_iters=0), our cached
    posterior equals GPy's SparseGPRegression (VarDTC) prediction, mean and latent variance."""
    import GPy

    rng = np.random.default_rng(1)
    X = rng.uniform(-2, 2, (400, 2))
    y = np.sin(2 * X[:, 0]) + 0.3 * X[:, 1] ** 2 + 0.1 * rng.standard_normal(400)
    model = SparseGPR(n_inducing=20, max_iters=0, lengthscale_init=[0.8, 1.2], noise_init=0.05, jitter=1e-8)
    with threadpool_limits(limits=1, user_api="blas"):
        model.fit(X, y)
    s2 = float(np.mean(y ** 2))
    kern = GPy.kern.Matern32(2, variance=s2, lengthscale=[0.8, 1.2], ARD=True)
    gp = GPy.models.SparseGPRegression(X, y[:, None], kernel=kern, Z=model.inducing_inputs_)
    gp.Gaussian_noise.variance = 0.05 * s2
    Xt = rng.uniform(-3, 3, (200, 2))
    gm, gv = gp.predict_noiseless(Xt)
    mean, std = model.predict(Xt, return_std=True)
    np.testing.assert_allclose(mean, gm[:, 0], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(std, np.sqrt(gv[:, 0]), rtol=1e-4, atol=1e-6)
    m1, s1 = model.predict_one(Xt[3])
    assert m1 == pytest.approx(mean[3], rel=1e-9) and s1 == pytest.approx(std[3], rel=1e-7)


def test_sgpr_with_fixed_inducing_inputs_fits_what_gpy_fits(monkeypatch):
    """Skipping the gradient with respect to fixed inducing inputs changes no number: the same
    hyper-parameters and posterior, bit for bit, as GPy's own SparseGPRegression."""
    import GPy

    from ciml_learning.learning.learners import sgpr

    rng = np.random.default_rng(3)
    X = rng.normal(size=(600, 4))
    y = np.sin(X[:, 0]) + 0.3 * X[:, 1] * X[:, 2] + 0.05 * rng.normal(size=600)
    params = {"n_inducing": 30, "n_hyper_samples": 400, "max_iters": 30}
    with threadpool_limits(limits=1, user_api="blas"):
        ours = SparseGPR(**params).fit(X, y).get_state()
        monkeypatch.setattr(sgpr, "_regression_class", lambda fixed_inducing: GPy.models.SparseGPRegression)
        stock = SparseGPR(**params).fit(X, y).get_state()
    assert ours.keys() == stock.keys()
    for key in ours:
        np.testing.assert_array_equal(ours[key], stock[key], err_msg=key)


def test_sgpr_falls_back_to_prior_and_round_trips():
    rng = np.random.default_rng(2)
    X = rng.uniform(-1, 1, (600, 3))
    y = 2.0 * X[:, 0] + np.sin(3 * X[:, 1]) + 0.05 * rng.standard_normal(600)
    with threadpool_limits(limits=1, user_api="blas"):
        model = SparseGPR(n_inducing=30, max_iters=30).fit(X, y)
    mean, std = model.predict(np.array([[0.0, 0.0, 0.0], [1e6, 1e6, 1e6]]), return_std=True)
    assert std[0] < 0.3 * std[1]
    assert abs(mean[1]) < 1e-9
    assert std[1] == pytest.approx(np.sqrt(model.kernel_variance_), rel=1e-6)
    clone = SparseGPR.from_state(model.get_params(), model.get_state())
    Xt = rng.uniform(-1, 1, (50, 3))
    np.testing.assert_array_equal(model.predict(Xt, return_std=True)[1], clone.predict(Xt, return_std=True)[1])


def test_kmeans_finds_separated_clusters():
    rng = np.random.default_rng(3)
    centres = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    X = np.vstack([c + 0.1 * rng.standard_normal((200, 2)) for c in centres])
    found = kmeans(X, 3, 10, rng)
    d = np.linalg.norm(found[:, None, :] - centres[None], axis=2)
    assert np.all(d.min(axis=0) < 0.1)


# ------------------------------------------------------------------------------ both learners
@pytest.mark.parametrize("learner", ["lwpr", "sgpr"])
def test_known_friction_error_learned_within_10_percent(learner):
    """Viscous + smooth Coulomb friction on one joint, Γ(q̇) = −(3 q̇ + 4 tanh(q̇/0.2)), learned
    from noisy (q, q̇, q̈) samples; RMSE against the true function on held-out executions
    (inside the training range) below 10 % of its RMS."""
    X, f, y = friction_data(10_000, seed=0)
    Xt, ft, _ = friction_data(3_000, seed=100, freq=(0.6, 1.8), amp=(0.12, 0.45))
    scale = 5.0  # standardised outputs, as the model set does
    if learner == "lwpr":
        model = LWPR(norm_in="auto", init_D=10.0, init_alpha=50.0, w_gen=0.2, n_epochs=2, shuffle=True)
    else:
        model = SparseGPR(n_inducing=50, n_hyper_samples=1000, max_iters=50)
    with threadpool_limits(limits=1, user_api="blas"):
        model.fit(X, y / scale)
    pred = model.predict(Xt) * scale
    assert relative_rmse(pred, ft) < 0.10


def test_contract_shared_by_both_learners():
    assert set(LEARNERS) == {"lwpr", "sgpr"}
    with pytest.raises(LearnerError, match="unknown learner"):
        learner_class("pickle")
    for cls in (LWPR, SparseGPR):
        model = cls()
        assert not model.is_fitted
        with pytest.raises(LearnerError, match="not fitted"):
            model.predict(np.zeros((1, 2)))
        params = model.get_params()
        assert cls.from_params(params).get_params() == params
        with pytest.raises(LearnerError, match="unknown"):
            cls.from_params({"no_such": 1})
    rng = np.random.default_rng(0)
    X, y = rng.normal(size=(200, 2)), rng.normal(size=200)
    model = LWPR()
    assert model.fit(X, y) is model and model.partial_fit(X, y) is model
    learned = [k for k in vars(model) if not k.startswith("_") and k not in model.get_params()]
    assert learned and all(k.endswith("_") for k in learned), learned
    with pytest.raises(LearnerError, match="non-finite"):
        LWPR().fit(np.array([[0.0, np.nan]]), np.array([1.0]))
    with pytest.raises(LearnerError, match="rows"):
        LWPR().fit(X, y[:10])
    with pytest.raises(LearnerError, match="features"):
        model.predict(np.zeros((1, 3)))
    with pytest.raises(LearnerError, match="invalid LWPR"):
        LWPR(w_gen=2.0)
    with pytest.raises(LearnerError, match="invalid lwpr state"):
        LWPR.from_state(model.get_params(), {**model.get_state(), "rf.c": np.zeros((3, 5))})
