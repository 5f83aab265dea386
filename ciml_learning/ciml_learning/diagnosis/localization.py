"""Where the gap lies: the size of the measured error per dimension, relative to the signal
and to the noise level, split by phase, contact configuration and speed.

Dimensions are the 18 entries of the contact-invariant error Φ̃' (eq. 11: base force and
torque, each foot's force while it swings) and the actuation error Γ of each joint (eq. 14).
For each: the RMS error [N or Nm] over the observed valid samples; its size relative to the
signal (the RMS of the measured joint torques seen through the same eq. (11) operator,
O Sᵀτ, for Φ̃'; of the measured torque τ_j for Γ_j); and its share of the gap: the part of
its noise-normalised sum of squares above the noise level (one unit per sample),
share_d = n_d · max(0, mean((e/σ_d)²) − 1) / Σ_d (…).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ciml_learning.core.robot import RobotDescription
from ciml_learning.diagnosis.features import Rows
from ciml_learning.logs.pipeline import Dataset

MIN_SAMPLES_PER_SPLIT = 25


def dimension_names(robot: RobotDescription) -> list[str]:
    """Φ̃' names (robot.rbd_error_names) then the actuators (joint names without '_joint')."""
    act = [j[: -len("_joint")] if j.endswith("_joint") else j for j in robot.joint_names]
    return list(robot.rbd_error_names) + act


def dimension_units(robot: RobotDescription) -> list[str]:
    """The unit of each of dimension_names: Nm for the base torques and the actuators, N otherwise."""
    n_rbd = len(robot.rbd_error_names)
    return ["Nm" if (d >= n_rbd or n in ("base_roll", "base_pitch", "base_yaw")) else "N"
            for d, n in enumerate(dimension_names(robot))]


def contact_label(robot: RobotDescription, contacts: np.ndarray) -> str:
    """'lf+lh+rf+rh' style label of the feet in contact ('flight' when none)."""
    on = [leg for leg, c in zip(robot.leg_names, contacts) if c]
    return "+".join(on) if on else "flight"


@dataclass
class DimensionErrors:
    """Per output dimension: measured error entries with their sample context."""

    name: str
    kind: str
    error: np.ndarray      # entries [N or Nm]
    signal: np.ndarray     # matching signal entries
    contacts: np.ndarray   # n × n_feet contact flags of each entry's sample
    speed: np.ndarray      # speed measure of each entry's sample (see localize)


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else 0.0


def collect(robot: RobotDescription, parts: list[tuple[Dataset, Rows]]) -> list[DimensionErrors]:
    """Error entries per dimension from (dataset, rows) pairs (identification and held-out).

    Speed: the base linear speed [m/s] for the base entries, the joint speed of the leg
    [rad/s] for its foot's entries and its actuators."""
    names = dimension_names(robot)
    n_rbd = 6 + 3 * robot.n_feet
    leg_of_joint = {j: i for i, leg in enumerate(robot.leg_joints) for j in leg}
    out = []
    for d in range(n_rbd + robot.n_joints):
        err, sig, con, spd = [], [], [], []
        for ds, r in parts:
            log = ds.log
            if d < n_rbd:
                m = r.dim_rbd == d
                smp = r.samples[r.sample_rbd[m]]
                err.append(r.y_rbd[m])
                sig.append(r.signal_rbd[m])
            else:
                j = d - n_rbd
                smp = r.samples
                err.append(r.y_act[:, j])
                sig.append(r.X_act[:, j, 1])  # the gain feature is τ_j
            con.append(log.contacts[smp])
            if d < 6:
                spd.append(np.linalg.norm(log.v[smp, :3], axis=1))
            else:
                leg = (d - 6) // 3 if d < n_rbd else leg_of_joint[d - n_rbd]
                spd.append(np.linalg.norm(log.v[smp][:, 6 + np.asarray(robot.leg_joints[leg])], axis=1))
        out.append(DimensionErrors(names[d], "rbd" if d < n_rbd else "actuation", np.concatenate(err),
                                   np.concatenate(sig), np.concatenate(con), np.concatenate(spd)))
    return out


def localize(robot: RobotDescription, parts: list[tuple[Dataset, Rows]], sigma: np.ndarray) -> list[dict]:
    """The localization list of diagnosis.json (docs/ARCHITECTURE.md §6), sorted by share, largest first."""
    dims = collect(robot, parts)
    n_rbd = 6 + 3 * robot.n_feet
    leg_of_joint = {j: i for i, leg in enumerate(robot.leg_joints) for j in leg}
    excess = []
    entries: list[dict[str, Any]] = []
    for d, de in enumerate(dims):
        n = len(de.error)
        ms = float(np.mean((de.error / sigma[d]) ** 2)) if n else 0.0
        excess.append(n * max(0.0, ms - 1.0))
        item: dict[str, Any] = {
            "dimension": de.name,
            "kind": de.kind,
            "rms_error": _rms(de.error),
            "share": 0.0,
            "relative_error": _rms(de.error) / max(_rms(de.signal), 1e-9) if n else 0.0,
            "signal_rms": _rms(de.signal),
            "noise_level": float(sigma[d]),
            "normalised_rms": float(np.sqrt(ms)),
            "samples": int(n),
        }
        if n:
            # phase: feet are observed only while they swing; base entries split by "all feet on the
            # ground" vs "some foot swinging"; an actuator by its own leg's phase
            if d < 6:
                stance = de.contacts.all(axis=1)
            elif d < n_rbd:
                stance = np.zeros(n, bool)
            else:
                stance = de.contacts[:, leg_of_joint[d - n_rbd]]
            item["by_phase"] = {k: _rms(de.error[m]) for k, m in (("stance", stance), ("swing", ~stance))
                                if m.sum() >= MIN_SAMPLES_PER_SPLIT}
            labels = np.array([contact_label(robot, c) for c in de.contacts])
            item["by_contacts"] = {str(lab): _rms(de.error[labels == lab]) for lab in np.unique(labels)
                                   if (labels == lab).sum() >= MIN_SAMPLES_PER_SPLIT}
            edges = np.quantile(de.speed, [1 / 3, 2 / 3])
            bins = {"slow": de.speed <= edges[0], "medium": (de.speed > edges[0]) & (de.speed <= edges[1]),
                    "fast": de.speed > edges[1]}
            item["by_speed"] = {k: _rms(de.error[m]) for k, m in bins.items() if m.sum() >= MIN_SAMPLES_PER_SPLIT}
            item["speed_edges"] = [float(e) for e in edges]
            item["speed_measure"] = "base linear speed [m/s]" if d < 6 else "leg joint speed [rad/s]"
        entries.append(item)
    total = sum(excess)
    for item, e in zip(entries, excess):
        item["share"] = float(e / total) if total > 0 else 0.0
    entries.sort(key=lambda x: (-x["share"], -x["normalised_rms"]))
    return entries


def leg_summary(robot: RobotDescription, localization: list[dict]) -> dict[str, float]:
    """Share of the gap per leg (its feet's Φ̃' entries and its actuators) and for the base."""
    out = {"base": 0.0}
    out.update({leg: 0.0 for leg in robot.leg_names})
    act = dimension_names(robot)[6 + 3 * robot.n_feet:]
    leg_of = {a: robot.leg_names[i] for i, leg in enumerate(robot.leg_joints) for a in [act[j] for j in leg]}
    for item in localization:
        name = item["dimension"]
        if name.startswith("base_"):
            out["base"] += item["share"]
        elif name.startswith("foot_"):
            out[name[len("foot_"):].rsplit("_", 1)[0]] += item["share"]
        elif name in leg_of:
            out[leg_of[name]] += item["share"]
    return out
