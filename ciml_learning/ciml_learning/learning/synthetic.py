"""Synthetic data with a known answer, for the benchmarks and the tests (not the product path).

- synthetic_training_set: a paper-sized training set (Φ̃, Γ and their truth) produced by the
  extraction's own conversions (eq. 8), with its helpers states_from_inputs, fit_arguments
  (ModelSet.fit's arguments) and relative_rmse (a fit scored against the truth);
- cross_function: the classic 2-D LWPR test function.
"""
from __future__ import annotations

import numpy as np

from ciml_learning.core.extraction import dynamics_batch, learning_input_names
from ciml_learning.core.projection import contact_invariant_bases, generalized_rbd_error, leg_coupling
from ciml_learning.learning.models import ModelSet


def synthetic_training_set(robot, n_samples: int = 54_000, seed: int = 0, noise: float = 1.0) -> dict[str, np.ndarray]:
    """A paper-sized synthetic training set with a known model error (benchmarks, tests).

    Inputs follow three fixed periodic gaits (0.6, 1.3 and 2.0 Hz), executed in 5 s
    segments that vary in frequency (±10 %), amplitudes (±15 %) and phases (a few
    degrees) — like repeated executions of the paper's training motions: joints around
    the standing posture, analytic q̇ and q̈, small roll/pitch and base motion, joint
    torques periodic around a static load with analytic τ̇, 1 % input noise. As in
    filtered HyQ logs, the data lie near low-dimensional cycles of the input space.
    Contacts follow a
    trot (diagonal pairs swing in turn) or a walk (one leg at a time); a foot's RBD
    entries are observed only during its swing, samples within 3 of a contact change
    are invalid; the contact timing relative to the joint motion varies between executions.

    The states are physical (base at 0.6 m, zero yaw, roll/pitch and joints from x), so the
    targets go through the extraction's own conversions: the true generalized error
    Φ̃ = [w; e] maps to Φ̃' = J'⁻ᵀΦ̃ (eq. 8) with HyQ's contact-invariant basis at each
    state, noise is added to the observed entries of Φ̃', and generalized_error,
    generalized_observed and leg_coupling follow as in extraction.extract — a stance leg's
    joint error reaches the measured base rows through C, as on the robot.

    True errors (returned as rbd_true = Φ̃ and actuation_true = Γ, noise-free; the same for
    every seed):
    - base wrench of a 5 kg payload at (0.1, 0.05, 0.05) m: m (R_bᵀ g + a_base), c × F;
    - each leg joint: a smooth friction-like a_j tanh(q̇_j / 0.3) + b_j sin(3 q_j) (a few Nm);
    - each actuator: viscous b_i q̇_i plus smooth Coulomb c_i tanh(q̇_i / 0.2) friction, a
      10 ms lag (−T τ̇_i) and, on the first joint, a 15 % torque loss (−0.15 τ_1).
    Measured Φ̃' adds Gaussian noise (2 N / 0.3 Nm base, 3 N feet), Γ 0.5 Nm, × noise.
    """
    rng = np.random.default_rng(seed)
    fs = 250.0
    nj, nf = robot.n_joints, robot.n_feet
    seg_len = int(5 * fs)
    X_parts: list[np.ndarray] = []
    C_parts: list[np.ndarray] = []
    # the gaits themselves are fixed (like the paper's motions); executions vary around them
    g_rng = np.random.default_rng(20180301)
    gaits = []
    for freq, kind in ((0.6, "walk"), (1.3, "walk"), (2.0, "trot")):
        psi = np.tile(g_rng.uniform(0, 2 * np.pi, 3), nf)[:nj] + np.repeat(np.arange(nf) * np.pi / 2, 3)[:nj]
        gaits.append(dict(freq=freq, kind=kind, amp=g_rng.uniform(0.08, 0.25, nj), amp2=g_rng.uniform(0.0, 0.06, nj),
                          psi=psi, base_amp=np.r_[g_rng.uniform(0.002, 0.008, 3), g_rng.uniform(0.01, 0.04, 3)],
                          base_psi=g_rng.uniform(0, 2 * np.pi, 6), speed=g_rng.uniform(0.1, 0.3),
                          load=g_rng.uniform(-40.0, 40.0, nj), load_amp=g_rng.uniform(10.0, 40.0, nj),
                          load_psi=g_rng.uniform(0, 2 * np.pi, nj)))
    k = 0
    while sum(len(p) for p in X_parts) < n_samples:
        g = gaits[k % len(gaits)]
        kind = g["kind"]
        k += 1
        t = np.arange(seg_len) / fs
        freq = g["freq"] * rng.uniform(0.9, 1.1)
        w = 2 * np.pi * freq
        phi = w * t + rng.uniform(0, 2 * np.pi)
        amp = g["amp"] * rng.uniform(0.85, 1.15, nj)
        amp2 = g["amp2"] * rng.uniform(0.85, 1.15, nj)
        psi = g["psi"] + rng.normal(0, 0.05, nj)
        q = robot.standing_joints + amp * np.sin(phi[:, None] + psi) + amp2 * np.sin(2 * phi[:, None] + psi)
        qd = w * (amp * np.cos(phi[:, None] + psi) + 2 * amp2 * np.cos(2 * phi[:, None] + psi))
        qdd = -w * w * (amp * np.sin(phi[:, None] + psi) + 4 * amp2 * np.sin(2 * phi[:, None] + psi))
        ba = g["base_amp"] * rng.uniform(0.8, 1.2, 6)
        bpsi = g["base_psi"] + rng.normal(0, 0.05, 6)
        base_pos = ba * np.sin(phi[:, None] + bpsi)           # x, y, z, roll, pitch, yaw-like
        base_vel = w * ba * np.cos(phi[:, None] + bpsi) + np.r_[g["speed"] * rng.uniform(0.8, 1.2), 0, 0, 0, 0, 0]
        base_acc = -w * w * base_pos
        roll_pitch = base_pos[:, 3:5]
        load_amp = g["load_amp"] * rng.uniform(0.85, 1.15, nj)
        tau = g["load"] + load_amp * np.sin(phi[:, None] + g["load_psi"])
        tau_dot = w * load_amp * np.cos(phi[:, None] + g["load_psi"])
        x = np.hstack([roll_pitch, q, base_vel, qd, base_acc, qdd, tau, tau_dot])
        x += 0.01 * noise * rng.standard_normal(x.shape) * np.abs(x).mean(axis=0)
        # contact timing varies between executions, so every joint state is seen swinging in some
        # execution (a leg joint's error is learned from swing samples and needed in stance too)
        ph = ((phi + rng.uniform(0, 2 * np.pi)) / (2 * np.pi)) % 1.0
        if kind == "trot":
            swing_a = ph < 0.5
            contacts = np.stack([swing_a if i % 3 == 0 else ~swing_a for i in range(nf)], axis=1)
            contacts = ~contacts
        else:
            contacts = np.stack([~((ph >= i / nf) & (ph < (i + 1) / nf)) for i in range(nf)], axis=1)
        X_parts.append(x)
        C_parts.append(contacts)
    X = np.vstack(X_parts)[:n_samples]
    contacts = np.vstack(C_parts)[:n_samples]
    names = learning_input_names(robot)
    assert X.shape[1] == len(names)
    idx = {n: i for i, n in enumerate(names)}
    roll, pitch = X[:, idx["base_roll"]], X[:, idx["base_pitch"]]
    g_base = 9.81 * np.stack([-np.sin(pitch), np.sin(roll) * np.cos(pitch), np.cos(roll) * np.cos(pitch)], axis=1)
    acc = X[:, [idx[f"qdd_{d}"] for d in robot.dof_names[:3]]]
    F = 5.0 * (g_base + acc)
    tau_base = np.cross(np.array([0.1, 0.05, 0.05]), F)
    q_j = X[:, [idx[f"q_{j}"] for j in robot.joint_names]]
    qd_j = X[:, [idx[f"qd_{j}"] for j in robot.joint_names]]
    tau_j = X[:, [idx[f"tau_{j}"] for j in robot.joint_names]]
    tau_dot_j = X[:, [idx[f"taud_{j}"] for j in robot.joint_names]]
    a_j, b_j = g_rng.uniform(2.0, 6.0, nj), g_rng.uniform(1.0, 3.0, nj)  # the same for every seed
    rbd_true = np.hstack([F, tau_base, a_j * np.tanh(qd_j / 0.3) + b_j * np.sin(3 * q_j)])
    b = g_rng.uniform(1.0, 4.0, nj)
    c = g_rng.uniform(1.0, 5.0, nj)
    act_true = -(b * qd_j + c * np.tanh(qd_j / 0.2)) - 0.01 * tau_dot_j
    act_true[:, 0] -= 0.15 * tau_j[:, 0]
    q, v, a = states_from_inputs(robot, X)
    basis = contact_invariant_bases(dynamics_batch(robot, q, v, a)[1], robot.leg_joints)
    phi_true = np.linalg.solve(np.transpose(basis, (0, 2, 1)), rbd_true[..., None])[..., 0]  # eq. (8)
    rbd_noise = np.r_[np.full(3, 2.0), np.full(3, 0.3), np.full(3 * nf, 3.0)] * noise
    rbd = phi_true + rng.standard_normal(phi_true.shape) * rbd_noise
    act = act_true + rng.standard_normal(act_true.shape) * 0.5 * noise
    observed = np.hstack([np.ones((n_samples, 6), dtype=bool), np.repeat(~contacts, 3, axis=1)])
    change = np.zeros(n_samples, dtype=bool)
    sw = np.flatnonzero(np.any(contacts[1:] != contacts[:-1], axis=1))
    for d in range(-3, 4):
        change[np.clip(sw + d, 0, n_samples - 1)] = True
    valid = ~change
    rbd_measured = np.where(observed, rbd, 0.0)  # like ExtractionResult: zero where unobserved
    generalized, generalized_observed = generalized_rbd_error(basis, rbd_measured, observed, robot.leg_joints)
    return {"inputs": X, "rbd_error": rbd_measured, "rbd_observed": observed, "generalized_error": generalized,
            "generalized_observed": generalized_observed, "leg_coupling": leg_coupling(basis, robot.leg_joints),
            "actuation_error": act, "valid": valid, "contacts": contacts, "rbd_true": rbd_true,
            "actuation_true": act_true, "q": q, "v": v, "a": a, "tau": tau_j, "tau_dot": tau_dot_j}


def states_from_inputs(robot, X: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pinocchio states (q, v, q̈) whose learning inputs (eq. 12 part) are X: base at (0, 0, 0.6) m
    with zero yaw, roll and pitch as its quaternion, the rest verbatim."""
    nj, nv = robot.n_joints, robot.nv
    half_roll, half_pitch = X[:, 0] / 2, X[:, 1] / 2
    cr, sr, cp, sp = np.cos(half_roll), np.sin(half_roll), np.cos(half_pitch), np.sin(half_pitch)
    q = np.zeros((len(X), robot.nq))
    q[:, 2] = 0.6
    q[:, 3:7] = np.stack([cp * sr, sp * cr, -sp * sr, cp * cr], axis=1)  # xyzw of R_y(pitch) R_x(roll)
    q[:, 7:] = X[:, 2:2 + nj]
    return q, X[:, 2 + nj:2 + nj + nv], X[:, 2 + nj + nv:2 + nj + 2 * nv]


def fit_arguments(data: dict[str, np.ndarray], rows=slice(None)) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                          np.ndarray, np.ndarray, np.ndarray]:
    """(X, Φ̃, mask, Γ, valid, C) of a synthetic_training_set, in ModelSet.fit's order."""
    X, R, M, A, V, C = (data[k][rows] for k in ("inputs", "generalized_error", "generalized_observed",
                                                "actuation_error", "valid", "leg_coupling"))
    return X, R, M, A, V, C


def relative_rmse(model_set: ModelSet, data: dict[str, np.ndarray]) -> dict[str, float]:
    """RMSE of the prediction against the true (noise-free) error relative to the RMS of
    the true error, per dimension, summarised per group (median, max). A leg joint's error
    is scored where it is observable (swing), as the learner only sees those."""
    pred = model_set.predict(data["inputs"], return_var=False)
    out = {}
    obs = data["generalized_observed"]
    for key, p, t, m in (("rbd", pred.rbd, data["rbd_true"], obs),
                         ("actuation", pred.actuation, data["actuation_true"], np.ones_like(pred.actuation, bool))):
        rel = np.array([np.sqrt(np.mean((p[m[:, i], i] - t[m[:, i], i]) ** 2) / np.mean(t[m[:, i], i] ** 2))
                        for i in range(p.shape[1])])
        out[f"{key}_relative_rmse_median"] = round(float(np.median(rel)), 4)
        out[f"{key}_relative_rmse_max"] = round(float(np.max(rel)), 4)
    return out


def cross_function(X: np.ndarray) -> np.ndarray:
    """The classic LWPR test function on [−1, 1]²: max(e^{−10x₁²}, e^{−50x₂²}, 1.25 e^{−5(x₁²+x₂²)})."""
    x1, x2 = X[:, 0], X[:, 1]
    return np.maximum.reduce([np.exp(-10 * x1 ** 2), np.exp(-50 * x2 ** 2), 1.25 * np.exp(-5 * (x1 ** 2 + x2 ** 2))])
