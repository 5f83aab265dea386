"""Sparse Gaussian-process regression with GPy: Matérn-3/2 ARD kernel, k-means inducing
inputs, hyper-parameters fitted on a subset, posterior on all data once.

Why not GPy's SparseGPRegression on everything: at the paper's scale (54,000 samples,
50-D inputs, 250 inducing inputs) one optimiser iteration takes ~15 s per output
dimension (docs/ARCHITECTURE.md §10), i.e. hours for the 18 rigid-body dimensions. The
hyper-parameters (kernel variance σ_f², ARD lengthscales ℓ, noise variance σ_n²) of a
smooth model error are well determined by a few thousand samples, so:

1. inducing inputs Z: k-means (k-means++ seeding, a few Lloyd iterations, see kmeans())
   of up to `kmeans_samples` points, in per-dimension standardised coordinates; M = n_inducing
   (paper: 100 per actuation dimension, 250 per rigid-body dimension);
2. hyper-parameters: GPy SparseGPRegression (Titsias' variational bound, VarDTC) on a
   random subset of `n_hyper_samples` points, Z fixed (or `hyper_inducing` k-means inputs:
   the step costs O(n M²)), L-BFGS-B for `max_iters`;
3. posterior on all N samples, once, with the hyper-parameters and Z fixed, from GPy's
   kernel evaluations K(Z, X) in chunks (O(N M²), no N × N matrix). In the whitened
   parameterisation v = L⁻¹u, Kuu = L Lᵀ, V = L⁻¹ Kuf:

       B = I + V Vᵀ / σ_n²,   B = L_B L_Bᵀ
       α = L⁻ᵀ B⁻¹ V y / σ_n²                          (predictive weights)
       μ(x) = k(x, Z) α
       σ²(x) = k(x, x) − ‖L⁻¹ k(Z, x)‖² + ‖L_B⁻¹ L⁻¹ k(Z, x)‖²

   which is the predictive distribution of GPy's VarDTC posterior (same mean and
   latent variance; the tests check it against GPy).

Prediction uses only cached arrays (Z, ℓ, σ_f², α, L⁻¹, L_B⁻¹L⁻¹) and a numpy
Matérn-3/2 (checked against GPy's kernel in the tests): no GPy object is kept, so a
saved model is plain arrays and GPy is imported only to fit. The prior mean is zero:
away from the data μ → 0 and σ² → σ_f² (the nominal model with its prior uncertainty).
std is the latent function's (noise-free) uncertainty; noise_variance_ is available.
"""
from __future__ import annotations

import functools
import math
import warnings
from typing import ClassVar

import numpy as np

from ciml_learning.learning.learners.base import Learner, LearnerError

SQRT3 = math.sqrt(3.0)


def matern32(X: np.ndarray, Z: np.ndarray, variance: float, lengthscale: np.ndarray) -> np.ndarray:
    """Matérn-3/2 ARD kernel k(x, z) = σ² (1 + √3 r) exp(−√3 r), r = ‖(x − z)/ℓ‖ (N × M)."""
    A = X / lengthscale
    B = Z / lengthscale
    r2 = (A * A).sum(1)[:, None] + (B * B).sum(1)[None, :] - 2.0 * (A @ B.T)
    r = np.sqrt(np.maximum(r2, 0.0))
    return variance * (1.0 + SQRT3 * r) * np.exp(-SQRT3 * r)


def kmeans(X: np.ndarray, k: int, iters: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding and `iters` Lloyd iterations (k × d centroids).

    Distances by ‖x‖² + ‖c‖² − 2 x·c (one BLAS product per iteration): for 10,000 × 50-D
    points and k = 250 this takes well under a second, where scipy.cluster.vq.kmeans2
    (no BLAS) took ~14 s on this machine. An empty cluster keeps its previous centroid.
    """
    n = len(X)
    x2 = (X * X).sum(1)
    centers = np.empty((k, X.shape[1]))
    centers[0] = X[rng.integers(n)]
    d2 = np.maximum(x2 - 2 * X @ centers[0] + centers[0] @ centers[0], 0.0)
    for j in range(1, k):
        total = d2.sum()
        i = rng.choice(n, p=d2 / total) if total > 0 else rng.integers(n)
        centers[j] = X[i]
        d2 = np.minimum(d2, np.maximum(x2 - 2 * X @ centers[j] + centers[j] @ centers[j], 0.0))
    for _ in range(iters):
        label = np.argmin((centers * centers).sum(1)[None, :] - 2 * X @ centers.T, axis=1)
        counts = np.bincount(label, minlength=k)
        sums = np.zeros_like(centers)
        np.add.at(sums, label, X)
        nonempty = counts > 0
        new = centers.copy()
        new[nonempty] = sums[nonempty] / counts[nonempty, None]
        if np.allclose(new, centers):
            break
        centers = new
    return centers


def _regression_class(fixed_inducing: bool):
    """GPy's SparseGPRegression, or with fixed inducing inputs _fixed_inducing_regression()."""
    import GPy

    return _fixed_inducing_regression() if fixed_inducing else GPy.models.SparseGPRegression


@functools.cache
def _fixed_inducing_regression():
    """SparseGPRegression without the gradient with respect to Z: GPy computes it whether Z is
    fixed or not (two kernel gradients_X calls per optimiser step, on both cores: ~40 % of a fit's
    CPU here); the kernel's and the noise's gradients are GPy's own, so every number is GPy's."""
    import GPy

    class FixedInducingRegression(GPy.models.SparseGPRegression):
        def _update_gradients(self) -> None:
            g = self.grad_dict
            self.likelihood.update_gradients(g["dL_dthetaL"])
            self.kern.update_gradients_diag(g["dL_dKdiag"], self.X)
            kerngrad = self.kern.gradient.copy()
            self.kern.update_gradients_full(g["dL_dKnm"], self.X, self.Z)
            kerngrad += self.kern.gradient
            self.kern.update_gradients_full(g["dL_dKmm"], self.Z, None)
            self.kern.gradient += kerngrad
            self.Z.gradient = 0.0

    return FixedInducingRegression


class SparseGPR(Learner):
    """Sparse GP regression (module docstring), one output.

    Hyper-parameters:
        n_inducing: number of inducing inputs M (capped at the number of samples).
        n_hyper_samples: subset size for the hyper-parameter optimisation.
        max_iters: L-BFGS-B iterations of the hyper-parameter optimisation.
        kmeans_samples, kmeans_iters: data and Lloyd iterations for the inducing inputs.
        optimize_inducing: also optimise Z on the subset (slow in high dimension).
        hyper_inducing: inducing inputs of the hyper-parameter step (None: n_inducing); fewer
            cost O(n M²) less per optimiser step, the posterior still uses n_inducing (k-means
            inputs; an optimize_inducing result of the smaller set is not kept).
        noise_init: initial noise variance as a fraction of the mean square target.
        lengthscale_init: initial ARD lengthscales (None: std of each input × √n_inputs).
        jitter: added to diag(Kuu), relative to σ_f².
        chunk_size: rows of K(Z, X) evaluated at once for the posterior.
        random_state: seed of the subset and of k-means.
    """

    name: ClassVar[str] = "sgpr"
    supports_partial_fit: ClassVar[bool] = False

    def __init__(
        self,
        n_inducing: int = 100,
        n_hyper_samples: int = 2000,
        max_iters: int = 100,
        kmeans_samples: int = 10000,
        kmeans_iters: int = 10,
        optimize_inducing: bool = False,
        hyper_inducing: int | None = None,
        noise_init: float = 0.1,
        lengthscale_init: float | list | None = None,
        jitter: float = 1e-6,
        chunk_size: int = 4096,
        random_state: int = 0,
    ) -> None:
        self.n_inducing = n_inducing
        self.n_hyper_samples = n_hyper_samples
        self.max_iters = max_iters
        self.kmeans_samples = kmeans_samples
        self.kmeans_iters = kmeans_iters
        self.optimize_inducing = optimize_inducing
        self.hyper_inducing = hyper_inducing
        self.noise_init = noise_init
        self.lengthscale_init = lengthscale_init
        self.jitter = jitter
        self.chunk_size = chunk_size
        self.random_state = random_state
        bad = [k for k, ok in {"n_inducing": int(n_inducing) >= 1, "n_hyper_samples": int(n_hyper_samples) >= 2,
                               "max_iters": int(max_iters) >= 0, "noise_init": noise_init > 0,
                               "hyper_inducing": hyper_inducing is None or int(hyper_inducing) >= 1,
                               "jitter": jitter > 0, "chunk_size": int(chunk_size) >= 1}.items() if not ok]
        if bad:
            raise LearnerError(f"invalid SparseGPR hyper-parameter(s) {bad}")

    # --------------------------------------------------------------- fitting
    def fit(self, X: np.ndarray, y: np.ndarray) -> "SparseGPR":
        """Inducing inputs, hyper-parameters on a subset, posterior on all of (X, y); returns self."""
        X, y = self._check_Xy(X, y)
        n, d = X.shape
        if n < 2:
            raise LearnerError(f"SparseGPR needs at least 2 samples, got {n}")
        rng = np.random.default_rng(self.random_state)
        scale = X.std(axis=0)
        scale = np.where(scale > 1e-9, scale, 1.0)
        Z = self._inducing_inputs(X, scale, rng, self.n_inducing)
        m_hyper = len(Z) if self.hyper_inducing is None else min(int(self.hyper_inducing), len(Z))
        if m_hyper < len(Z):
            Zh = self._inducing_inputs(X, scale, rng, m_hyper)
            variance, lengthscale, noise, _ = self._optimize_hyperparameters(X, y, Zh, scale, rng)
        else:
            variance, lengthscale, noise, Z = self._optimize_hyperparameters(X, y, Z, scale, rng)
        self._posterior(X, y, Z, variance, lengthscale, noise)
        return self

    def _inducing_inputs(self, X: np.ndarray, scale: np.ndarray, rng: np.random.Generator, m: int) -> np.ndarray:
        n = len(X)
        m = int(min(m, n))
        idx = rng.choice(n, size=min(n, int(self.kmeans_samples)), replace=False)
        S = X[idx] / scale
        if m >= len(S):
            return X[idx[:m]].copy()
        return kmeans(S, m, int(self.kmeans_iters), rng) * scale

    def _optimize_hyperparameters(self, X, y, Z, scale, rng):
        import GPy

        n, d = X.shape
        idx = rng.choice(n, size=min(n, int(self.n_hyper_samples)), replace=False)
        Xs, ys = X[idx], y[idx]
        s2 = max(float(np.mean(ys * ys)), 1e-12)
        if self.lengthscale_init is None:
            ls0 = scale * math.sqrt(d)
        else:
            ls0 = np.broadcast_to(np.asarray(self.lengthscale_init, dtype=float), (d,)).copy()
        kern = GPy.kern.Matern32(d, variance=s2, lengthscale=ls0, ARD=True)
        model = _regression_class(fixed_inducing=not self.optimize_inducing)(Xs, ys[:, None], kernel=kern,
                                                                              Z=Z.copy())
        model.Gaussian_noise.variance = self.noise_init * s2
        # the noise cannot vanish: floor at 1e-6 of the signal (keeps B well conditioned)
        model.Gaussian_noise.variance.constrain_bounded(1e-6 * s2, 10.0 * s2, warning=False)
        if not self.optimize_inducing:
            model.inducing_inputs.fix(warning=False)
        if int(self.max_iters) > 0:
            try:
                with warnings.catch_warnings(), np.errstate(all="ignore"):
                    warnings.simplefilter("ignore")
                    model.optimize("lbfgsb", max_iters=int(self.max_iters), messages=False)
            except (np.linalg.LinAlgError, ValueError, FloatingPointError) as err:
                raise LearnerError(f"SparseGPR hyper-parameter optimisation failed: {err}") from err
        variance = float(model.kern.variance.values[0])
        lengthscale = np.asarray(model.kern.lengthscale.values, dtype=float).copy()
        noise = float(model.Gaussian_noise.variance.values[0])
        Z = np.asarray(model.inducing_inputs.values, dtype=float).copy()
        if not (np.isfinite(variance) and variance > 0 and np.all(np.isfinite(lengthscale))
                and np.all(lengthscale > 0) and np.isfinite(noise) and noise > 0):
            raise LearnerError("SparseGPR hyper-parameter optimisation returned non-finite values")
        return variance, lengthscale, noise, Z

    def _posterior(self, X, y, Z, variance, lengthscale, noise) -> None:
        # GPy and scipy only to fit: the nodes that predict (model server, online learner) import
        # this module and stay free of both
        import GPy
        from scipy.linalg import cho_factor, solve_triangular

        m, d = Z.shape
        kern = GPy.kern.Matern32(d, variance=variance, lengthscale=lengthscale, ARD=True)
        Kuu = kern.K(Z) + self.jitter * variance * np.eye(m)
        try:
            L = np.linalg.cholesky(Kuu)
        except np.linalg.LinAlgError as err:
            raise LearnerError("SparseGPR: K(Z, Z) is not positive definite (duplicate inducing inputs?)") from err
        A = np.zeros((m, m))
        b = np.zeros(m)
        step = int(self.chunk_size)
        for i in range(0, len(X), step):
            V = solve_triangular(L, kern.K(Z, X[i:i + step]), lower=True)  # M × chunk
            A += V @ V.T
            b += V @ y[i:i + step]
        B = np.eye(m) + A / noise
        LB, _ = cho_factor(B, lower=True)
        LB = np.tril(LB)
        Linv = solve_triangular(L, np.eye(m), lower=True)
        LBLinv = solve_triangular(LB, Linv, lower=True)
        alpha = LBLinv.T @ solve_triangular(LB, b / noise, lower=True)  # L⁻ᵀ B⁻¹ V y / σ_n²
        self.n_features_in_ = d
        self.n_samples_fit_ = len(X)
        self.inducing_inputs_ = Z
        self.lengthscale_ = lengthscale
        self.kernel_variance_ = variance
        self.noise_variance_ = noise
        self.alpha_ = alpha
        self.Linv_ = Linv
        self.LBLinv_ = LBLinv
        self._cache()

    # --------------------------------------------------------------- prediction
    def predict(self, X: np.ndarray, return_std: bool = False):
        """Mean (N,) or (mean, std) of the latent function at X (N × n_features)."""
        self._check_fitted()
        X = self._check_X(X, self.n_features_in_)
        return self._predict(X, return_std)

    def _cache(self) -> None:
        """Z/ℓ and ‖Z/ℓ‖² for the kernel evaluations of prediction."""
        self._Zs = self.inducing_inputs_ / self.lengthscale_
        self._zz = (self._Zs * self._Zs).sum(1)

    def _kernel(self, X: np.ndarray) -> np.ndarray:
        A = X / self.lengthscale_
        r2 = (A * A).sum(1)[:, None] + self._zz[None, :] - 2.0 * (A @ self._Zs.T)
        r = np.sqrt(np.maximum(r2, 0.0))
        return self.kernel_variance_ * (1.0 + SQRT3 * r) * np.exp(-SQRT3 * r)

    def _predict(self, X: np.ndarray, return_std: bool):
        out_mean = np.empty(len(X))
        out_std = np.empty(len(X))
        step = int(self.chunk_size)
        for i in range(0, len(X), step):
            K = self._kernel(X[i:i + step])
            out_mean[i:i + step] = K @ self.alpha_
            if return_std:
                a1 = K @ self.Linv_.T
                a2 = K @ self.LBLinv_.T
                var = self.kernel_variance_ - (a1 * a1).sum(1) + (a2 * a2).sum(1)
                out_std[i:i + step] = np.sqrt(np.maximum(var, 0.0))
        return (out_mean, out_std) if return_std else out_mean

    def predict_one(self, x: np.ndarray) -> tuple[float, float]:
        """Fast (mean, std) at one input x (n,) — online use, no input checks."""
        a = np.asarray(x, dtype=float) / self.lengthscale_
        r = np.sqrt(np.maximum(a @ a + self._zz - 2.0 * (self._Zs @ a), 0.0))
        k = self.kernel_variance_ * (1.0 + SQRT3 * r) * np.exp(-SQRT3 * r)
        a1 = self.Linv_ @ k
        a2 = self.LBLinv_ @ k
        var = self.kernel_variance_ - a1 @ a1 + a2 @ a2
        return float(k @ self.alpha_), math.sqrt(var) if var > 0.0 else 0.0

    def summary(self) -> dict:
        """A few JSON-able numbers describing the fitted model (for model.json and logs)."""
        ls = self.lengthscale_
        return {"inducing": int(len(self.alpha_)), "samples": int(self.n_samples_fit_),
                "kernel_std": round(math.sqrt(self.kernel_variance_), 6),
                "noise_std": round(math.sqrt(self.noise_variance_), 6),
                "lengthscale_min": round(float(ls.min()), 6), "lengthscale_median": round(float(np.median(ls)), 6)}

    # --------------------------------------------------------------- state
    def get_state(self) -> dict[str, np.ndarray]:
        self._check_fitted()
        return {
            "inducing_inputs": self.inducing_inputs_,
            "lengthscale": self.lengthscale_,
            "kernel_variance": np.array([self.kernel_variance_]),
            "noise_variance": np.array([self.noise_variance_]),
            "alpha": self.alpha_,
            "Linv": self.Linv_,
            "LBLinv": self.LBLinv_,
            "n_samples_fit": np.array([self.n_samples_fit_]),
        }

    def _set_state(self, arrays: dict[str, np.ndarray]) -> None:
        Z = np.asarray(arrays["inducing_inputs"], dtype=float)
        if Z.ndim != 2 or Z.shape[0] < 1:
            raise ValueError(f"inducing_inputs has shape {Z.shape}")
        m, d = Z.shape
        expected = {"lengthscale": (d,), "kernel_variance": (1,), "noise_variance": (1,), "alpha": (m,),
                    "Linv": (m, m), "LBLinv": (m, m), "n_samples_fit": (1,)}
        vals = {}
        for key, shape in expected.items():
            a = np.asarray(arrays[key], dtype=float)
            if a.shape != shape:
                raise ValueError(f"{key} has shape {a.shape}, expected {shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{key} holds non-finite values")
            vals[key] = a
        if np.any(vals["lengthscale"] <= 0) or vals["kernel_variance"][0] <= 0 or vals["noise_variance"][0] <= 0:
            raise ValueError("kernel variance, lengthscales and noise variance must be positive")
        if not np.all(np.isfinite(Z)):
            raise ValueError("inducing_inputs holds non-finite values")
        self.n_features_in_ = d
        self.n_samples_fit_ = int(vals["n_samples_fit"][0])
        self.inducing_inputs_ = Z
        self.lengthscale_ = vals["lengthscale"]
        self.kernel_variance_ = float(vals["kernel_variance"][0])
        self.noise_variance_ = float(vals["noise_variance"][0])
        self.alpha_ = vals["alpha"]
        self.Linv_ = vals["Linv"]
        self.LBLinv_ = vals["LBLinv"]
        self._cache()
