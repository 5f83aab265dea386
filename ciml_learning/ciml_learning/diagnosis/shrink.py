"""How far the gap shrinks: the held-out residual with the identified effects added to the
nominal model, per dimension (physical units) and overall (noise-normalised).

Overall: RMS over every held-out observed entry of e/σ_d (each dimension in units of its
noise level, identification.py), nominal vs with the effects; ratio = 1 − with / nominal,
the fraction of the gap removed. The same overall number in physical units (N and Nm mixed)
is given as `heldout_rms_*_physical` for reference.

Stiction. A joint friction that sticks (Coulomb, Stribeck: EffectType.stiction) is set-valued at
rest: while its joint does not move (|q̇_j| < V_STICK) its torque is whatever holds the joint,
anywhere in [−f_s, f_s] (f_s the level it holds with), not a function of the state. The
identification therefore projects a stuck joint's torque out of its samples, as eq. (11) projects
out the contact forces (project_stuck; run.identify). On held-out rows the friction torque at a
stuck sample is estimated per sample as the projection of the residual onto that joint's torque
direction (O_k e_j, eq. 11), clipped to ±f_s — the set-valued law with the identified level. The
shrink is given with and without this per-sample estimate.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ciml_learning.diagnosis.features import Rows, predict
from ciml_learning.diagnosis.identification import Model, physical_parameters
from ciml_learning.diagnosis.localization import dimension_names, dimension_units

V_STICK = 0.05
"""[rad/s] a joint slower than this may be stuck by its friction."""
STICK_SEEN = 1e-6
"""A row sees joint j's torque when |O_k e_j| in it exceeds this (rows are in N or Nm per Nm)."""


def stuck_rows(rows: Rows, v_joints: np.ndarray, j: int) -> np.ndarray:
    """Rows (bool over the Φ̃' rows) of samples where joint j may be stuck (v_joints: N × n_j of
    rows.samples) that see its torque."""
    stuck = (np.abs(v_joints[:, j]) < V_STICK)[rows.sample_rbd]
    return stuck & (np.abs(rows.X_rbd[:, rows.layout.torque0 + j]) > STICK_SEEN)


def _stuck_bases(rows: Rows, v_joints: np.ndarray, joints: list[int], sigma: np.ndarray):
    """Per group of samples with the same number of Φ̃' rows m and of stuck joints of `joints` (that
    their rows see): (row indices B × m, σ_d of each row B × m × 1, orthonormal bases B × m × n_j of the
    whitened directions O_k e_j of the stuck joints)."""
    if not joints or len(rows.y_rbd) == 0:
        return
    cols = rows.layout.torque0 + np.asarray(joints)
    seen = np.column_stack([stuck_rows(rows, v_joints, j) for j in joints])
    n_s = len(rows.samples)
    hits = np.zeros((n_s, len(joints)), int)
    np.add.at(hits, rows.sample_rbd, seen.astype(int))
    stuck = hits > 0
    count = np.bincount(rows.sample_rbd, minlength=n_s)
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    n_stuck = stuck.sum(axis=1)
    scale = np.asarray(sigma, float)[rows.dim_rbd]
    for m in np.unique(count[n_stuck > 0]):
        for n_j in np.unique(n_stuck[(count == m) & (n_stuck > 0)]):
            ks = np.flatnonzero((count == m) & (n_stuck == n_j))
            idx = start[ks][:, None] + np.arange(m)
            which = np.argsort(~stuck[ks], axis=1, kind="stable")[:, :n_j]
            w = scale[idx][..., None]
            Q, _ = np.linalg.qr(rows.X_rbd[idx[:, :, None], cols[which][:, None, :]].astype(float) / w)
            yield idx, w, Q


def project_stuck(rows: Rows, v_joints: np.ndarray, joints: list[int], sigma: np.ndarray) -> Rows:
    """The rows with the torque of every stuck joint of `joints` projected out, sample by sample: like
    a contact force (eq. 11), the torque holding a stuck joint is an unknown in [−f_s, f_s], so each
    sample's Φ̃' rows (whitened by σ_d, the selection's weights) are projected onto the complement of
    the directions O_k e_j of its stuck joints, then scaled back. The weighted normal equations of the
    result are those of the projected problem; a sample loses one direction per stuck joint, not its rows."""
    X, y, g = rows.X_rbd.copy(), rows.y_rbd.copy(), rows.signal_rbd.copy()
    for idx, w, Q in _stuck_bases(rows, v_joints, joints, sigma):
        for arr in (X, y, g):
            part = arr[idx]
            a = part.reshape(idx.shape + (-1,)).astype(float) / w
            arr[idx] = ((a - Q @ (Q.transpose(0, 2, 1) @ a)) * w).reshape(part.shape)
    return Rows(rows.layout, rows.samples, X, y, rows.dim_rbd, rows.sample_rbd, rows.X_act, rows.y_act, g,
                rows.raw_G, rows.raw_signal, rows.n_raw)


def stuck_ss(rows: Rows, values: np.ndarray, v_joints: np.ndarray, joints: list[int], sigma: np.ndarray) -> np.ndarray:
    """Per column of `values` (M_r × K, one row per Φ̃' row): the whitened sum of squares, over all
    samples, in the directions project_stuck removes."""
    out = np.zeros(values.shape[1])
    for idx, w, Q in _stuck_bases(rows, v_joints, joints, sigma):
        out += np.sum((Q.transpose(0, 2, 1) @ (values[idx] / w)) ** 2, axis=(0, 1))
    return out


@dataclass
class Residuals:
    """Held-out (or any) rows: measured errors and residuals after the identified effects."""

    rbd: np.ndarray          # M_r residual Φ̃' entries
    act: np.ndarray          # N × n_j residual Γ
    rbd_no_stiction: np.ndarray
    stiction_gain: dict      # candidate label → weighted SS removed by its stiction estimate


def residuals(rows: Rows, model: Model, weights: np.ndarray, v_joints: np.ndarray) -> Residuals:
    """Residuals of `rows` under the model, with the stiction estimate of each friction that sticks.

    v_joints: joint velocities of rows.samples (N × n_j)."""
    from ciml_learning.effects import EFFECTS

    lay = rows.layout
    theta = model.feature_theta()
    pr, pa = predict(rows, theta)
    res = rows.y_rbd - pr
    base = res.copy()
    wr = weights[rows.dim_rbd]
    n_s = len(rows.samples)
    gains = {}
    for cand, params in zip(model.candidates, physical_parameters(model)):
        kind = EFFECTS.get(cand.type)
        f_s = kind.stiction(params) if kind is not None else None
        if not f_s or f_s <= 0:
            continue
        j = lay.robot.joint_names.index(cand.joint)
        stuck = stuck_rows(rows, v_joints, j)
        if not stuck.any():
            continue
        before = float(np.sum(wr * res ** 2))
        d = rows.X_rbd[:, lay.torque0 + j].astype(float)
        own = model.part([cand]).feature_theta()[:lay.n_rbd]
        cols = np.flatnonzero(own)
        r2 = res.copy()
        r2[stuck] += rows.X_rbd[np.ix_(stuck, cols)] @ own[cols]  # the sliding law does not apply
        idx = rows.sample_rbd[stuck]
        num = np.bincount(idx, weights=(wr * d * r2)[stuck], minlength=n_s)
        den = np.bincount(idx, weights=(wr * d * d)[stuck], minlength=n_s)
        torque = np.clip(np.divide(num, den, out=np.zeros(n_s), where=den > 0), -f_s, f_s)
        r2[stuck] -= torque[idx] * d[stuck]
        res = r2
        gains[cand.label] = before - float(np.sum(wr * res ** 2))
    return Residuals(rbd=res, act=rows.y_act - pa, rbd_no_stiction=base, stiction_gain=gains)


def _overall(rows: Rows, rbd_res: np.ndarray, act_res: np.ndarray, sigma: np.ndarray) -> tuple[float, float]:
    n_rbd = len(sigma) - rows.y_act.shape[1]
    z = np.sum((rbd_res / sigma[rows.dim_rbd]) ** 2) + np.sum((act_res / sigma[n_rbd:]) ** 2)
    phys = np.sum(rbd_res ** 2) + np.sum(act_res ** 2)
    n = len(rbd_res) + act_res.size
    return float(np.sqrt(z / max(n, 1))), float(np.sqrt(phys / max(n, 1)))


WORSE_TOLERANCE = 0.01
"""A dimension is listed as made worse when its held-out RMS with the effects exceeds the nominal by more
than this fraction (1 %: changes in the last digits of a dimension the effects barely touch are not listed)."""


def shrink(robot, rows: Rows, res: Residuals, sigma: np.ndarray, floor: np.ndarray | None = None) -> dict:
    """The `shrink` object of diagnosis.json (docs/ARCHITECTURE.md §6) from held-out rows.

    Per dimension: the physical RMS [N or Nm] (rms_nominal, rms_with_effects, `unit`) next to the
    noise-normalised one (÷ σ_d), and the noise floor [N or Nm] (identification.noise_floor)
    with the share of the gap above it that the effects remove. `worsened_dimensions` lists every
    dimension the effects make worse (physical RMS up), and the overall numbers are given both
    noise-normalised (`ratio`, the contract) and in physical units, each dimension weighted alike
    (`ratio_physical_per_dimension`: RMS over dimensions of their physical RMS)."""
    names = dimension_names(robot)
    n_rbd = len(sigma) - rows.y_act.shape[1]
    units = dict(zip(names, dimension_units(robot)))
    per_dim: dict[str, dict[str, Any]] = {}
    for d, name in enumerate(names):
        if d < n_rbd:
            m = rows.dim_rbd == d
            if not m.any():
                continue
            y, e = rows.y_rbd[m], res.rbd[m]
        else:
            y, e = rows.y_act[:, d - n_rbd], res.act[:, d - n_rbd]
            if len(y) == 0:
                continue
        nom = float(np.sqrt(np.mean(y ** 2)))
        wth = float(np.sqrt(np.mean(e ** 2)))
        entry = {"rms_nominal": nom, "rms_with_effects": wth, "unit": units[name],
                 "ratio": float(1.0 - wth / nom) if nom > 0 else 0.0, "samples": int(len(y)),
                 "rms_nominal_normalised": nom / float(sigma[d]), "rms_with_effects_normalised": wth / float(sigma[d])}
        if floor is not None:
            f = float(floor[d])
            above = nom ** 2 - f ** 2
            entry["noise_floor"] = f
            entry["ratio_above_noise_floor"] = (float(np.clip((nom ** 2 - wth ** 2) / above, -np.inf, 1.0))
                                                if above > 1e-12 * max(nom ** 2, 1e-300) else 0.0)
        per_dim[name] = entry
    nom, nom_p = _overall(rows, rows.y_rbd, rows.y_act, sigma)
    wth, wth_p = _overall(rows, res.rbd, res.act, sigma)
    wns, _ = _overall(rows, res.rbd_no_stiction, res.act, sigma)
    worse = sorted(((n, e) for n, e in per_dim.items()
                    if e["rms_with_effects"] > e["rms_nominal"] * (1 + WORSE_TOLERANCE)),
                   key=lambda x: x[1]["ratio"])
    pd_nom = float(np.sqrt(np.mean([e["rms_nominal"] ** 2 for e in per_dim.values()]))) if per_dim else 0.0
    pd_wth = float(np.sqrt(np.mean([e["rms_with_effects"] ** 2 for e in per_dim.values()]))) if per_dim else 0.0
    extra = {
        "worsened_dimensions": [{"dimension": n, "rms_nominal": e["rms_nominal"],
                                 "rms_with_effects": e["rms_with_effects"], "unit": e["unit"], "ratio": e["ratio"]}
                                for n, e in worse],
        "ratio_physical_per_dimension": float(1.0 - pd_wth / pd_nom) if pd_nom > 0 else 0.0,
    }
    if floor is not None:
        extra["noise_floor_rms_physical"] = float(np.sqrt(np.mean([e["noise_floor"] ** 2 for e in per_dim.values()]))) \
            if per_dim else 0.0
    out = {
        "heldout_rms_nominal": nom,
        "heldout_rms_with_effects": wth,
        "ratio": float(1.0 - wth / nom) if nom > 0 else 0.0,
        "metric": "RMS over all held-out observed entries of Phi~' and Gamma, each divided by its "
                  "dimension's noise level (localization[].noise_level)",
        "ratio_without_stiction_estimate": float(1.0 - wns / nom) if nom > 0 else 0.0,
        "heldout_rms_nominal_physical": nom_p,
        "heldout_rms_with_effects_physical": wth_p,
        "ratio_physical": float(1.0 - wth_p / nom_p) if nom_p > 0 else 0.0,
        "per_dimension": per_dim,
    }
    out.update(extra)
    return out


def residual_series(rows: Rows, res: Residuals, sigma: np.ndarray, t: np.ndarray) -> dict:
    """Per held-out sample: time and the RMS over its observed entries of e/σ_d, nominal vs with
    the effects (for the report's over-time plot)."""
    n_s = len(rows.samples)
    n_rbd = len(sigma) - rows.y_act.shape[1]
    nom_sq, with_sq, cnt = np.zeros(n_s), np.zeros(n_s), np.zeros(n_s)
    s_r = sigma[rows.dim_rbd]
    np.add.at(nom_sq, rows.sample_rbd, (rows.y_rbd / s_r) ** 2)
    np.add.at(with_sq, rows.sample_rbd, (res.rbd / s_r) ** 2)
    np.add.at(cnt, rows.sample_rbd, 1.0)
    sa = sigma[n_rbd:]
    nom_sq += ((rows.y_act / sa) ** 2).sum(axis=1)
    with_sq += ((res.act / sa) ** 2).sum(axis=1)
    cnt += rows.y_act.shape[1]
    cnt = np.maximum(cnt, 1)
    return {"t": t[rows.samples], "nominal": np.sqrt(nom_sq / cnt), "with_effects": np.sqrt(with_sq / cnt)}
