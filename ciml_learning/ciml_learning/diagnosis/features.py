"""Regression rows of the diagnosis: every observed entry of Φ̃' (eq. 11) and of Γ (eq. 14)
with the candidate features at that sample.

Rows of the rigid-body kind are (sample, Φ̃' dimension) pairs where the dimension is observed
(base always, a foot while it swings) and the sample is valid; their features are the
candidate generalized forces passed through the sample's eq. (11) operator O_k, exactly as
the measured error was. Rows of the actuation kind are (sample, joint) pairs.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ciml_learning.core.extraction import observation_operators
from ciml_learning.core.projection import contact_invariant_bases
from ciml_learning.core.robot import RobotDescription
from ciml_learning.core.threads import in_order
from ciml_learning.diagnosis.candidates import (
    N_ACT,
    FeatureLayout,
    RegressorEvaluator,
    actuation_features,
    coulomb_regressor,
    effect_joint_regressors,
    generic_joint_basis,
)

CHUNK = 1000


@dataclass
class Rows:
    """Regression rows of a set of samples (see module docstring)."""

    layout: FeatureLayout
    samples: np.ndarray    # dataset indices of the samples these rows come from (sorted)
    X_rbd: np.ndarray      # M_r × n_rbd features (float32)
    y_rbd: np.ndarray      # M_r measured Φ̃' entries
    dim_rbd: np.ndarray    # M_r Φ̃' dimension (0 … 17)
    sample_rbd: np.ndarray  # M_r position in `samples`
    X_act: np.ndarray      # N × n_j × N_ACT actuation features (lag, gain, offset, sensor probe)
    y_act: np.ndarray      # N × n_j measured Γ
    signal_rbd: np.ndarray  # M_r the measured joint torques seen through eq. (11), O Sᵀτ (the "signal")
    raw_G: np.ndarray | None = None       # nv × n_rbd × n_rbd: Σ_k E_k[i]ᵀ E_k[i], features before eq. (11)
    raw_signal: np.ndarray | None = None  # nv: Σ_k s_k,i², s = (M q̈ + h) for the base, τ for the joints
    n_raw: int = 0                        # samples in raw_G (a subset keeps its parent's)

    @property
    def n_dims(self) -> int:
        return 6 + 3 * self.layout.robot.n_feet + self.layout.robot.n_joints

    def subset(self, keep: np.ndarray) -> "Rows":
        """Rows of the samples where keep (bool over `samples`) is True."""
        keep = np.asarray(keep, bool)
        new_pos = np.cumsum(keep) - 1
        r_keep = keep[self.sample_rbd]
        return Rows(self.layout, self.samples[keep], self.X_rbd[r_keep], self.y_rbd[r_keep], self.dim_rbd[r_keep],
                    new_pos[self.sample_rbd[r_keep]], self.X_act[keep], self.y_act[keep], self.signal_rbd[r_keep],
                    self.raw_G, self.raw_signal, self.n_raw)


def command_rate(log) -> np.ndarray:
    """u̇ (N × n_j) of the low-passed command, per segment (central differences)."""
    out = np.zeros_like(log.u)
    for s in np.unique(log.segment):
        idx = np.flatnonzero(log.segment == s)
        if len(idx) >= 2:
            out[idx] = np.gradient(log.u[idx], log.t[idx], axis=0)
    return out


def build_rows(robot: RobotDescription, layout: FeatureLayout, dataset, samples: np.ndarray,
               progress: bool = True, desc: str = "regressors") -> Rows:
    """Features and targets of the given dataset samples (valid ones only are used)."""
    log, targets = dataset.log, dataset.targets
    samples = np.asarray(samples, dtype=int)
    samples = samples[targets.valid[samples]]
    # the regressors pass through the same low-pass as the log: designed for each log's rate
    fs = log.segment_rate_hz if log.segment_rate_hz is not None else log.rate_hz
    coulomb = coulomb_regressor(log.v[:, 6:], log.segment, fs=fs)
    joint_extra = effect_joint_regressors(log.v[:, 6:], log.segment, fs=fs)
    generic = generic_joint_basis(log.q[:, 7:], layout, log.segment, fs=fs)
    u_dot = command_rate(log)
    ev = RegressorEvaluator(robot, layout)
    Xr, yr, dr, sr, gr = [], [], [], [], []
    nv = robot.nv
    raw_G = np.zeros((nv, layout.n_rbd, layout.n_rbd))
    raw_signal = np.zeros(nv)
    chunks = [samples[i:i + CHUNK] for i in range(0, len(samples), CHUNK)]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(samples), desc=desc, unit="sample", leave=False, mininterval=0.5)
    def regressors(idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A chunk's features E, operators O of eq. (11) and rows Φ̃' = O E (run on a worker thread)."""
        E, jac = ev.chunk(log.q[idx], log.v[idx], log.a[idx], log.contacts[idx], targets.residual[idx], coulomb[idx],
                          u_dot[idx], generic[idx], log.tau[idx], {t: x[idx] for t, x in joint_extra.items()})
        basis = contact_invariant_bases(jac, robot.leg_joints)
        O, _ = observation_operators(jac, basis, log.contacts[idx])
        return E, O, O @ E  # batched matmul (BLAS), = einsum("nij,njf->nif")

    for c_i, (idx, (E, O, phi)) in enumerate(zip(chunks, in_order(regressors, chunks))):
        for i, cols in enumerate(np.any(E != 0.0, axis=0)):  # Σ_n E[n, i]ᵀ E[n, i] on the features coordinate i loads
            Ei = E[:, i, cols]
            raw_G[i][np.ix_(cols, cols)] += Ei.T @ Ei
        raw_signal[:6] += np.sum(targets.residual[idx, :6] ** 2, axis=0)  # Sᵀτ has no base rows: r = −(M q̈ + h)
        raw_signal[6:] += np.sum(log.tau[idx] ** 2, axis=0)
        sig = np.einsum("nij,nj->ni", O[:, :, 6:], log.tau[idx]) if nv > 6 else np.zeros((len(idx), nv))
        mask = targets.rbd_observed[idx]
        n_i, d_i = np.nonzero(mask)
        Xr.append(phi[n_i, d_i].astype(np.float32))
        yr.append(targets.rbd_error[idx][n_i, d_i])
        dr.append(d_i)
        sr.append(n_i + c_i * CHUNK)
        gr.append(sig[n_i, d_i])
        if bar is not None:
            bar.update(len(idx))
    if bar is not None:
        bar.close()
    n_r = layout.n_rbd

    def cat(parts, shape, dt):
        return np.concatenate(parts) if parts else np.zeros(shape, dt)

    return Rows(
        layout=layout,
        samples=samples,
        X_rbd=cat(Xr, (0, n_r), np.float32),
        y_rbd=cat(yr, (0,), float),
        dim_rbd=cat(dr, (0,), int),
        sample_rbd=cat(sr, (0,), int),
        X_act=actuation_features(log.tau[samples], log.tau_dot[samples], generic[samples]),
        y_act=targets.actuation_error[samples].copy(),
        signal_rbd=cat(gr, (0,), float),
        raw_G=raw_G,
        raw_signal=raw_signal,
        n_raw=len(samples),
    )


@dataclass
class Grams:
    """Sufficient statistics of a set of rows, per output dimension d (Φ̃' dims, then joints):
    G[d] = Xᵀ X, c[d] = Xᵀ y, s[d] = yᵀ y, n[d] = number of rows (features: the full layout)."""

    G: np.ndarray
    c: np.ndarray
    s: np.ndarray
    n: np.ndarray

    def weighted(self, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        return (np.einsum("d,dij->ij", w, self.G), w @ self.c, float(w @ self.s))

    def ss(self, theta_f: np.ndarray) -> np.ndarray:
        """Residual sum of squares per dimension for feature coefficients theta_f."""
        return self.s - 2 * self.c @ theta_f + np.einsum("i,dij,j->d", theta_f, self.G, theta_f)


def grams(rows: Rows) -> Grams:
    """Per-dimension Gram matrices of the rows over all features (float64 accumulation)."""
    lay = rows.layout
    nf, n_rbd_dims, nj = lay.n_features, 6 + 3 * lay.robot.n_feet, lay.robot.n_joints
    D = n_rbd_dims + nj
    G = np.zeros((D, nf, nf))
    c = np.zeros((D, nf))
    s = np.zeros(D)
    n = np.zeros(D)
    nr = lay.n_rbd
    for d in range(n_rbd_dims):
        m = rows.dim_rbd == d
        if not m.any():
            continue
        X = rows.X_rbd[m].astype(float)
        y = rows.y_rbd[m]
        G[d, :nr, :nr] = X.T @ X
        c[d, :nr] = X.T @ y
        s[d] = y @ y
        n[d] = m.sum()
    for j in range(nj):
        X = rows.X_act[:, j, :]
        y = rows.y_act[:, j]
        f = lay.actuation_block(j)
        G[n_rbd_dims + j][np.ix_(f, f)] = X.T @ X
        c[n_rbd_dims + j, f] = X.T @ y
        s[n_rbd_dims + j] = y @ y
        n[n_rbd_dims + j] = len(y)
    return Grams(G, c, s, n)


def predict(rows: Rows, theta_f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted Φ̃' row values (M_r) and Γ (N × n_j) for feature coefficients theta_f."""
    lay = rows.layout
    rbd = rows.X_rbd.astype(float) @ theta_f[:lay.n_rbd]
    nj = lay.robot.n_joints
    act_theta = theta_f[lay.act0:].reshape(nj, N_ACT)
    act = np.einsum("njk,jk->nj", rows.X_act, act_theta)
    return rbd, act
