"""`ciml verify`: how far the sim-to-real gap shrinks, measured by re-simulation (docs/DIAGNOSIS.md,
"The re-simulated shrink").

The real logs' motions run again in the simulator three ways: nominal (no effect), with the
diagnosis' identified scenario (DIR/identified_scenario.yaml) and, when the user passes it, with the
oracle (the true scenario, for benchmarks). Each re-simulated log goes through the same reader,
filter and extraction as the real one (ciml_learning.logs.pipeline.load_dataset), and the gap is what the
two logs show for the same motion at the same time since its start: per dimension, the RMS
difference of the extracted model error (Φ̃' of eq. (11) and Γ of eq. (14)) and, apart, of the
measured joint torques.

Seeds and noise: every re-simulation is noise-free (the identified scenario holds no sensor noise and
the oracle's is dropped): an independent noise draw cannot match the real log's sample by sample and
would only add its variance to every column. The plant's seed drives the sensor noise alone, so the
re-simulations use seed 0.
"""
from __future__ import annotations

import dataclasses
import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription
from ciml_learning.diagnosis.localization import dimension_names, dimension_units
from ciml_learning.diagnosis.shrink import WORSE_TOLERANCE
from ciml_learning.logs import bagio

from .recorder import CONTROL_RATE, SENSOR_RATES, check_motion, record_bag
from .scenario import Scenario, nominal_scenario

COLUMNS = ("nominal", "identified", "oracle")
RESOLUTION = 1e-3
"""A dimension's gap changes below this fraction of the overall nominal gap are not counted as made worse."""
SEED = 0
"""The re-simulations' plant seed: it draws the sensor noise only, and they run without noise."""


class VerifyError(CimlError):
    """A log cannot be re-simulated (no motion named, unknown motion, too long)."""


@dataclass
class Signals:
    """What one log shows, per sample: t [s] since the motion start; values (N × D): Φ̃' (eq. 11), Γ
    (eq. 14) and the low-passed measured torques τ; observed (N × D): valid and observed (a foot's
    Φ̃' while it swings, Γ when the log has the command)."""

    t: np.ndarray
    values: np.ndarray
    observed: np.ndarray
    rate_hz: float


def bag_motion(path: str) -> tuple[str, int] | None:
    """(motion, its start stamp [ns]) of a log, or None when it names none: a `ciml record` bag names
    it in its metadata (bagio.MOTION_KEY; stamps are time since the start), a log of the live graph
    on /reference (the first message's motion and stamp)."""
    motion = bagio.custom_data(path).get(bagio.MOTION_KEY) if os.path.isdir(path) else None
    if motion:
        return motion, 0
    first = bagio.first_message(path, topics.REFERENCE)
    if first is None or not first[1].motion:
        return None
    return str(first[1].motion), first[0]


def log_signals(robot: RobotDescription, path: str, start_ns: int) -> Signals:
    """Signals of one bag, read, filtered and extracted as the diagnosis reads it."""
    from ciml_learning.logs.pipeline import load_dataset

    ds = load_dataset(robot, [path], progress=False)
    tg, n_j = ds.targets, robot.n_joints
    ok = tg.valid[:, None]
    gamma_seen = np.full((len(tg.t), n_j), ds.u_observed)
    observed = np.hstack([tg.rbd_observed, gamma_seen, np.ones((len(tg.t), n_j), bool)]) & ok
    values = np.hstack([tg.rbd_error, tg.actuation_error, ds.log.tau])
    return Signals(t=ds.log.t - start_ns * 1e-9, values=values, observed=observed, rate_hz=ds.rate_hz)


def squared_differences(real: Signals, sim: Signals) -> tuple[np.ndarray, np.ndarray]:
    """(Σ (real − sim)², count) per dimension over the samples of both logs at the same time since the
    motion start (within half a sample period) where both observe the dimension."""
    if len(sim.t) == 0:
        return np.zeros(real.values.shape[1]), np.zeros(real.values.shape[1], int)
    j = np.clip(np.searchsorted(sim.t, real.t), 1, len(sim.t) - 1)
    j -= np.abs(sim.t[j - 1] - real.t) < np.abs(sim.t[j] - real.t)  # the nearer neighbour
    close = np.abs(sim.t[j] - real.t) <= 0.5 / max(real.rate_hz, sim.rate_hz)
    both = real.observed & sim.observed[j] & close[:, None]
    diff = np.where(both, real.values - sim.values[j], 0.0)
    return np.sum(diff ** 2, axis=0), np.sum(both, axis=0)


def _sensor_rate(rate_hz: float) -> float:
    """The simulator's sensor rate nearest the log's measured rate."""
    return min(SENSOR_RATES, key=lambda r: abs(r - rate_hz))


def resimulate(robot: RobotDescription, scenario: Scenario, motion: str, duration: float, sensor_rate: float,
               scratch: str, name: str) -> tuple[Signals, bool]:
    """Record `motion` with `scenario` (noise-free, seed SEED) into scratch/name and read it back:
    (its signals, whether the robot fell)."""
    quiet = dataclasses.replace(scenario, sensor_noise={})
    out = os.path.join(scratch, name)
    result, _ = record_bag(robot, quiet, motion, duration, SEED, out, ground_truth=False, progress=False,
                           sensor_rate=sensor_rate)
    return log_signals(robot, out, 0), result.fell


def _gaps(ss: np.ndarray, n: np.ndarray) -> np.ndarray:
    return np.where(n > 0, np.sqrt(ss / np.maximum(n, 1)), np.nan)


def _overall(gaps: np.ndarray) -> float | None:
    """Every dimension weighted alike (N and Nm): the RMS of the per-dimension gaps."""
    g = gaps[np.isfinite(gaps)]
    return float(np.sqrt(np.mean(g ** 2))) if len(g) else None


def _shrink(nominal: float | None, other: float | None) -> float | None:
    """1 − gap / nominal gap: the fraction of the gap the simulator removes."""
    if nominal is None or other is None or nominal <= 0:
        return None
    return 1.0 - other / nominal


def _block(names: Sequence[str], units: Sequence[str], sums: dict[str, tuple[np.ndarray, np.ndarray]]) -> dict:
    """Per dimension and overall gaps and shrinks of one block of dimensions."""
    gaps = {c: _gaps(*sums[c]) for c in sums}
    per_dim: dict[str, dict[str, Any]] = {}
    for d, (name, unit) in enumerate(zip(names, units)):
        if not np.isfinite(gaps["nominal"][d]):
            continue
        entry: dict[str, Any] = {"unit": unit, "samples": int(sums["nominal"][1][d])}
        for c in sums:
            entry[f"gap_{c}"] = float(gaps[c][d]) if np.isfinite(gaps[c][d]) else None
        for c in sums:
            if c != "nominal":
                entry["shrink" if c == "identified" else f"shrink_{c}"] = _shrink(entry["gap_nominal"],
                                                                                  entry[f"gap_{c}"])
        per_dim[name] = entry
    overall: dict[str, Any] = {f"gap_{c}": _overall(gaps[c]) for c in sums}
    overall["shrink"] = _shrink(overall["gap_nominal"], overall["gap_identified"])
    if "oracle" in sums:
        overall["shrink_oracle"] = _shrink(overall["gap_nominal"], overall["gap_oracle"])
        overall["shrink_of_oracle"] = (overall["shrink"] / overall["shrink_oracle"]
                                       if overall["shrink"] is not None and overall["shrink_oracle"] else None)
    overall["further_than_nominal"] = (overall["gap_identified"] is not None and overall["gap_nominal"] is not None
                                       and overall["gap_identified"] > overall["gap_nominal"])
    # the diagnosis' 1 % tolerance, and an absolute one: a dimension both simulators match to rounding
    # (Γ of a joint without actuator effect: 10⁻¹² Nm) is not made worse by a change in its last digits
    floor = RESOLUTION * (overall["gap_nominal"] or 0.0)
    worse = [n for n, e in per_dim.items() if e["gap_identified"] is not None
             and e["gap_identified"] > e["gap_nominal"] * (1 + WORSE_TOLERANCE) + floor]
    return {"overall": overall, "per_dimension": per_dim, "worsened_dimensions": worse}


def verify(robot: RobotDescription, logs: Sequence[tuple[str, str, int]], identified: Scenario,
           oracle: Scenario | None = None) -> dict:
    """The re-simulated shrink of (bag, motion, motion start [ns]) logs: `resimulated_shrink` (the model
    error's dimensions), `torque` (the joint torques) and per bag what ran."""
    columns = {"nominal": nominal_scenario(), "identified": identified}
    if oracle is not None:
        columns["oracle"] = oracle
    names = dimension_names(robot)
    units = dimension_units(robot)
    n_err = len(names)
    tau_names = [f"tau_{n}" for n in names[n_err - robot.n_joints:]]
    dims = n_err + robot.n_joints
    sums = {c: (np.zeros(dims), np.zeros(dims, int)) for c in columns}
    bags = []
    with tempfile.TemporaryDirectory(prefix="ciml-verify-") as scratch:
        for i, (bag, motion, start_ns) in enumerate(logs):
            real = log_signals(robot, bag, start_ns)
            duration = float(np.ceil((real.t[-1] + 1e-9) * CONTROL_RATE) / CONTROL_RATE)
            if not 0 < duration <= 3600:
                raise VerifyError(f"{bag}: the log spans {duration:.3f} s after the motion start; verify re-simulates "
                                  "(0, 3600] s")
            row: dict = {"bag": bag, "motion": motion, "duration_s": duration, "fell": {}, "samples": {}}
            for c, scenario in columns.items():
                sim, fell = resimulate(robot, scenario, motion, duration, _sensor_rate(real.rate_hz), scratch,
                                       f"{c}_{i}")
                ss, n = squared_differences(real, sim)
                sums[c][0][:] += ss
                sums[c][1][:] += n
                row["fell"][c], row["samples"][c] = fell, int(n[:n_err].max(initial=0))
            bags.append(row)
    err = {c: (s[:n_err], n[:n_err]) for c, (s, n) in sums.items()}
    tau = {c: (s[n_err:], n[n_err:]) for c, (s, n) in sums.items()}
    return {"resimulated_shrink": _block(names, units, err),
            "torque": _block(tau_names, ["Nm"] * robot.n_joints, tau),
            "bags": bags, "seed": SEED, "sensor_noise": "none (re-simulations are noise-free)"}


def summary_lines(result: dict) -> list[str]:
    """A short text summary: overall gaps and shrinks, the largest dimensions."""
    lines = []
    for key, what in (("resimulated_shrink", "model error (Φ̃', Γ)"), ("torque", "joint torques")):
        o = result[key]["overall"]
        cols = [c for c in COLUMNS if f"gap_{c}" in o]
        gaps = ", ".join(f"{c} {o[f'gap_{c}']:.3f}" for c in cols if o[f"gap_{c}"] is not None)
        shr = f"shrink {o['shrink']:.1%}" if o["shrink"] is not None else "shrink n/a"
        if o.get("shrink_oracle") is not None:
            shr += f" (oracle {o['shrink_oracle']:.1%})"
        lines.append(f"{what}: gap RMS over dimensions [N, Nm] {gaps}; {shr}"
                     + ("; the identified simulator is FURTHER than the nominal one" if o["further_than_nominal"]
                        else ""))
    per = result["resimulated_shrink"]["per_dimension"]
    top = sorted(per, key=lambda n: -(per[n]["gap_nominal"] or 0.0))[:3]
    lines.append("largest gaps: " + "; ".join(
        f"{n} {per[n]['gap_nominal']:.2f} -> {per[n]['gap_identified']:.2f} {per[n]['unit']}" for n in top))
    worse = result["resimulated_shrink"]["worsened_dimensions"]
    if worse:
        lines.append("made worse: " + ", ".join(worse))
    return lines


def check_logs(bags: Sequence[str], motion: str | None) -> list[tuple[str, str, int]]:
    """(bag, motion, motion start [ns]) of each bag; a bag that names no motion takes `motion` (--motion),
    else a one-line VerifyError."""
    out = []
    for bag in bags:
        found = bag_motion(bag)
        if found is None:
            if motion is None:
                raise VerifyError(f"{bag} names no motion (no /reference topic, no {bagio.MOTION_KEY} in its "
                                  "metadata): verify re-simulates the log's motion; give --motion NAME")
            found = (motion, 0)
        check_motion(found[0])
        out.append((bag, *found))
    return out
