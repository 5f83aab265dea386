#!/usr/bin/env python3
"""Side by side with the peer: CIML (not told the effect) and mujoco.sysid (told the family).

Issue 22, item 6. On gap-bench cases whose bags already exist (``ciml gap-bench --out DIR``
records them, without ground truth, into DIR/case_NN/{train,heldout}_K), per case:

1. **CIML**: ``ciml diagnose --bag train... --heldout heldout...`` as a separate process, timed
   here (it is not told the effect: it reads the bags only). The value, std and intervals of the
   effect of the true type and place are read from its diagnosis.json.
2. **mujoco.sysid** (MuJoCo's system-identification toolbox, ``from mujoco import sysid``; needs
   the ``mujoco[sysid]`` extra: absl-py, colorama, jinja2, plotly, tabulate, or the import is
   silently empty) **told the parameter family** (which parameter of which joint or body),
   fitting it by rollouts of the robot's MuJoCo model against the same training bags:

   - model: the nominal MJCF of the robot (ciml_sim.mjcf.build_mjcf, the simulator's own model
     without the scenario: the best case for the peer, no structural error) with the joint
     friction constraint settings of the simulator (ciml_sim.plant FRICTION_SOLREF/SOLIMP);
   - actuators: replaying the measured 250 Hz torque open loop diverges within tens of ms, so
     the 1 kHz joint loop is rebuilt from the logged TorqueCommand as MuJoCo actuators: one
     general actuator per joint, force = ctrl − K_p q − K_d q̇ (affine bias, the logged gains,
     which are constant in these logs), clipped to the URDF torque limit, with ctrl at each
     1 ms step = u_ff + u_lin + K_p q_t + K_d q̇_t + K_p q̇_t (s − t_c) of the command in force;
   - data: short windows (``--window`` s) starting at measured states (q, v of the bag), spread
     evenly over each training bag (``--windows`` per bag); observations: every joint's
     position and velocity (``<joint>_qpos``, ``<joint>_qvel``), the toolbox's default residual
     (measured − predicted at the measured stamps, normalised per signal);
   - optimiser: ``sysid.optimize`` (the toolbox's default "mujoco" least squares, finite
     differences with step ``--fd-step``: at the default 1.5e-8 the payload's CoM never moves),
     interval: ``sysid.calculate_intervals`` on the residual and Jacobian at the
     optimum (95 % and 68 %).

   Families (what the user had to specify):
   payload (a point mass m at p in the base frame: a massless-inertia child body of the base;
   ``sysid.body_inertia_param(..., InertiaType.Mass)`` fails on mujoco 4.0.0, see --probe),
   joint Coulomb friction (the joint's ``frictionloss``), joint viscous friction (the joint's
   ``damping``, a 3-vector in mujoco 4's spec: its first entry), torque gain (the actuator's
   gain and bias scaled by g, force range ±g τ_max).

3. **Each tool's updated model, re-simulated** (issue 29 item 6): the same question for both, "how
   far is the simulator with what the tool found from the logs": ``ciml verify --real HELDOUT...
   --diagnosis D --oracle BENCH/answers/case_NN.yaml`` re-records the held-out bags' motions nominal,
   with D/identified_scenario.yaml and with the truth, and reports the gap metric of
   docs/DIAGNOSIS.md. CIML's D is its diagnosis; mujoco.sysid's is OUT/case_NN_sysid, whose
   identified_scenario.yaml the user would write by hand and this script writes for it
   (sysid_scenario: the told family's effect with the fitted values), so both answers run in the
   same simulator with the same motions, seeds and metric (CIML's verify.json is gap-bench's own
   when it verified the same identified scenario: run_verify). ``--no-resim`` skips this.

``--check`` also rolls the windows out with the TRUE parameter (from the gap-bench suite) and
with the nominal model, to show the reconstruction reproduces the logs (the truth's residual
must be far below the nominal one).

    nice -n 10 .venv/bin/python tools/sysid_compare.py --bench out/gap_bench --cases 1 2 4 6 \\
        --out out/sysid_compare [--window 0.3 --windows 6 --max-iters 30 --check --no-resim]

Writes OUT/sysid_compare.json (every number of results/SYSID_COMPARISON.md) and prints a table.
The truth comes from ciml_sim.gapbench.SUITE and is used only to score (and for --check);
neither CIML nor the sysid fit is given it.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CIML = os.path.join(os.path.dirname(sys.executable), "ciml")
T95, T68 = 0.05, 0.32  # alpha of calculate_intervals for the 95 % and 68 % intervals


# --- the logs ------------------------------------------------------------------------------


@dataclass
class Log:
    """One bag as arrays (robot joint order): sample times t, Pinocchio q and v, and the
    commands (stamp, c = u_ff + u_lin + K_p q_t + K_d q̇_t, rate K_p q̇_t, gains)."""

    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    stamp: np.ndarray
    c: np.ndarray
    c_rate: np.ndarray
    kp: np.ndarray
    kd: np.ndarray


def read_log(robot, bag: str) -> Log:
    from ciml_learning.logs.bagio import read_messages
    from ciml_learning.logs.loginputs import load_log

    s = load_log(robot, bag)
    # rosbags deserializes into message classes it generates at run time: untyped
    msgs: list[Any] = [m for _, m in read_messages(bag, ["/torque_command"])["/torque_command"]]
    order = [list(msgs[0].joint_names).index(n) for n in robot.joint_names]
    stamp = np.array([m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec for m in msgs])
    f = {k: np.array([np.asarray(getattr(m, k), float)[order] for m in msgs])
         for k in ("feedforward", "feedback_linearization", "position_target", "velocity_target", "stiffness",
                   "damping")}
    if any(m.mode != 0 for m in msgs):
        raise SystemExit(f"{bag}: damping-mode commands; the actuator reconstruction assumes torque mode")
    kp, kd = f["stiffness"], f["damping"]
    if np.ptp(kp, axis=0).max() > 0 or np.ptp(kd, axis=0).max() > 0:
        raise SystemExit(f"{bag}: the PD gains change; the fixed-gain actuators cannot rebuild this joint loop")
    c = f["feedforward"] + f["feedback_linearization"] + kp * f["position_target"] + kd * f["velocity_target"]
    return Log(s.t, s.q, s.v, stamp, c, kp * f["velocity_target"], kp[0], kd[0])


# --- the model -----------------------------------------------------------------------------


def nominal_spec(robot, kp: np.ndarray, kd: np.ndarray, lag: bool = False):
    """The robot's nominal MJCF with the joint loop as actuators (module docstring); with `lag`,
    each actuator filters its ctrl (MuJoCo dyntype filterexact, time constant dynprm[0]): the
    activation state must exist in the model the windows' initial states are made for."""
    import mujoco

    from ciml_sim.mjcf import build_mjcf
    from ciml_sim.plant import FRICTION_SOLIMP, FRICTION_SOLREF

    spec = mujoco.MjSpec.from_string(build_mjcf(robot))
    for j, name in enumerate(robot.joint_names):
        joint = spec.joint(name)
        joint.solref_friction = list(FRICTION_SOLREF)
        joint.solimp_friction = list(FRICTION_SOLIMP)
        a = spec.actuator(name)
        a.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        a.gainprm[0] = 1.0
        a.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        a.biasprm[0], a.biasprm[1], a.biasprm[2] = 0.0, -kp[j], -kd[j]
        a.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        a.forcerange = [-robot.torque_limits[j], robot.torque_limits[j]]
        if lag:
            a.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
            a.dynprm[0] = 0.005
    return spec


@dataclass
class Family:
    """A parameter family as the user tells it to mujoco.sysid: names, nominal, bounds, how it
    modifies the spec, and how the truth of the gap-bench scenario reads in its terms."""

    kind: str
    where: str
    names: list[str]
    nominal: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    apply: object  # (spec, value) -> None
    told: str
    truth: np.ndarray = field(default_factory=lambda: np.zeros(0))


def family_of(effect: dict, robot, kp: np.ndarray, kd: np.ndarray) -> Family:

    t = effect["type"]
    if t == "payload":
        def apply(spec, v):
            b = spec.body("base").add_body()
            b.name, b.pos, b.ipos = "payload", [0.0, 0.0, 0.0], list(v[1:4])  # the mass at ipos of the base frame
            b.mass, b.inertia, b.explicitinertial = float(v[0]), [1e-9, 1e-9, 1e-9], True
        return Family(t, "base", ["mass", "com_x", "com_y", "com_z"], np.array([1.0, 0.0, 0.0, 0.0]),
                      np.array([0.0, -0.5, -0.5, -0.5]), np.array([60.0, 0.5, 0.5, 0.5]), apply,
                      "a point mass [kg] at a point [m] of the base: a child body 'payload' of the base, "
                      "mass 0-60 kg, position within ±0.5 m; start 1 kg at the origin",
                      np.array([effect["mass"], *effect["com"]], float))
    j = robot.joint_names.index(effect["joint"])
    name = effect["joint"]
    if t == "joint_coulomb_friction":
        def apply(spec, v):
            spec.joint(name).frictionloss = float(v[0])
        return Family(t, name, ["value"], np.array([1.0]), np.array([0.0]), np.array([50.0]), apply,
                      f"frictionloss of {name} [Nm], 0-50, start 1", np.array([effect["value"]]))
    if t == "joint_viscous_friction":
        def apply(spec, v):
            d = np.array(spec.joint(name).damping, float)
            d[0] = float(v[0])
            spec.joint(name).damping = d
        return Family(t, name, ["value"], np.array([1.0]), np.array([0.0]), np.array([50.0]), apply,
                      f"damping of {name} [Nm s/rad] (first entry of mujoco 4's 3-vector), 0-50, start 1",
                      np.array([effect["value"]]))
    if t == "torque_gain":
        lim = robot.torque_limits[j]

        def apply(spec, v):
            a = spec.actuator(name)
            g = float(v[0])
            a.gainprm[0], a.biasprm[1], a.biasprm[2] = g, -g * kp[j], -g * kd[j]
            a.forcerange = [-g * lim, g * lim]
        return Family(t, name, ["value"], np.array([1.0]), np.array([0.5]), np.array([2.0]), apply,
                      f"gain g of the {name} actuator (gain and bias × g, force range ±g τ_max), 0.5-2, start 1",
                      np.array([effect["value"]]))
    raise SystemExit(f"no mujoco.sysid family written for effect type {t!r} (payload, joint Coulomb/viscous "
                     f"friction, torque gain, actuator lag)")


def lag_family(effect: dict) -> Family:
    """Actuator lag of every joint: one time constant of MuJoCo's actuator filter (dyntype
    filterexact). MuJoCo filters ctrl only; the bias (here the joint loop's K_p q + K_d q̇ feedback)
    is not filtered, while the simulated actuator lags the whole u: the closest the toolbox's
    actuator model gets, not the same model."""
    def apply(spec, v):
        for a in spec.actuators:
            a.dynprm[0] = float(v[0])
    return Family("actuator_lag", "all", ["time_constant"], np.array([0.005]), np.array([0.0005]),
                  np.array([0.1]), apply, "one time constant [s] of a first-order filter on every actuator's ctrl "
                  "(dyntype filterexact; the PD feedback in the bias is not filtered), 0.5-100 ms, start 5 ms",
                  np.array([effect["time_constant"]]))


# --- windows -------------------------------------------------------------------------------


def windows(model, log: Log, seconds: float, count: int, skip: float = 0.5):
    """(initial state, control TimeSeries, measured TimeSeries) of `count` windows of the log."""
    from mujoco import sysid

    from ciml_sim.mjcf import pin_to_mj_state

    dt = model.opt.timestep
    per = round(0.004 / dt)
    n_samples = round(seconds / 0.004)
    first = int(np.searchsorted(log.t, log.t[0] + skip))
    starts = np.linspace(first, len(log.t) - n_samples - 1, count).astype(int)
    joints = [model.joint(i).name for i in range(1, model.njnt)]
    names = [f"{n}_qpos" for n in joints] + [f"{n}_qvel" for n in joints]
    out = []
    for i in starts:
        qpos, qvel = pin_to_mj_state(log.q[i], log.v[i])
        steps = n_samples * per
        s = log.t[i] + dt * np.arange(steps + 1)
        k = np.searchsorted(log.stamp, s + 1e-9, side="right") - 1  # the command in force at each step
        ctrl = log.c[k] + log.c_rate[k] * (s - log.stamp[k])[:, None]
        # a filtered actuator starts at rest at its first ctrl (its state is not in the log)
        x0 = sysid.create_initial_state(model, qpos, qvel, act=ctrl[0].copy() if model.na else None)
        control = sysid.TimeSeries.from_control_names(s - log.t[i], ctrl, model)
        rows = slice(i, i + n_samples + 1)
        meas = np.hstack([log.q[rows, 7:], log.v[rows, 6:]])
        sensors = sysid.TimeSeries.from_names(log.t[rows] - log.t[i], meas, model, names)
        out.append((x0, control, sensors))
    return out


# --- the two tools -------------------------------------------------------------------------


def run_ciml(case_dir: str, out_dir: str) -> tuple[dict, float, float]:
    bags = sorted(d for d in os.listdir(case_dir) if d.startswith("train_"))
    held = sorted(d for d in os.listdir(case_dir) if d.startswith("heldout_"))
    cmd = [CIML, "diagnose", "--bag", *[os.path.join(case_dir, b) for b in bags],
           "--heldout", *[os.path.join(case_dir, b) for b in held], "--out", out_dir]
    t0, c0 = time.perf_counter(), _children_cpu()
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    wall, cpu = time.perf_counter() - t0, _children_cpu() - c0
    with open(os.path.join(out_dir, "diagnosis.json"), encoding="utf-8") as f:
        return json.load(f), wall, cpu


def sysid_scenario(effect: dict, fam: Family, value: list[float]) -> dict:
    """mujoco.sysid's answer as a ciml_sim scenario (what its user would write to run it in CIML's
    simulator): the effect of the family it was told (the truth's type and place) with the fitted
    values in the family's units, which are the scenario's (payload: mass, com; else the one field)."""
    from ciml_learning.effects.scenario import outside_range

    params = ({"mass": value[0], "com": list(value[1:4])} if fam.kind == "payload"
              else {fam.names[0]: value[0]})
    entry = {**effect, **params}
    problem = outside_range(entry)
    if problem:
        raise SystemExit(f"mujoco.sysid's {problem}: the simulator cannot run it")
    return {"name": "sysid", "seed": 0, "sensor_noise": {}, "effects": [entry],
            "description": "written by tools/sysid_compare.py: mujoco.sysid's fitted family"}


def run_verify(case_dir: str, diagnosis_dir: str, oracle: str, out_dir: str) -> dict:
    """`ciml verify` of the case's held-out bags with diagnosis_dir/identified_scenario.yaml and the
    truth as the oracle: the overall re-simulated gaps (model error and joint torques) and its wall time.
    When gap-bench already verified the same identified scenario (case_dir/verify/verify.json of a
    case_dir/diagnosis/identified_scenario.yaml with the same effects, numbers within 1e-9 relative:
    the diagnosis is deterministic but for the last digits of its sums), its verify.json is read
    instead (the re-simulation is deterministic too), with `reused` set."""
    import yaml

    from ciml_learning.diagnosis.files import IDENTIFIED_SCENARIO

    def effects(path: str) -> list:
        if not os.path.isfile(path):
            return []
        with open(path, encoding="utf-8") as f:
            return yaml.safe_load(f)["effects"]

    def same(a: object, b: object) -> bool:
        if isinstance(a, dict) and isinstance(b, dict):
            return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
        if isinstance(a, list) and isinstance(b, list):
            return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
        if isinstance(a, float) or isinstance(b, float):
            return (isinstance(a, (int, float)) and isinstance(b, (int, float))
                    and bool(np.isclose(a, b, rtol=1e-9, atol=0.0)))
        return a == b

    bench_verify = os.path.join(case_dir, "verify", "verify.json")
    ours = effects(os.path.join(diagnosis_dir, IDENTIFIED_SCENARIO))
    reused = (os.path.isfile(bench_verify) and bool(ours)
              and same(ours, effects(os.path.join(case_dir, "diagnosis", IDENTIFIED_SCENARIO))))
    held = sorted(os.path.join(case_dir, d) for d in os.listdir(case_dir) if d.startswith("heldout_"))
    t0 = time.perf_counter()
    if not reused:
        subprocess.run([CIML, "verify", "--real", *held, "--diagnosis", diagnosis_dir, "--oracle", oracle,
                        "--out", out_dir], check=True, capture_output=True, text=True)
    with open(bench_verify if reused else os.path.join(out_dir, "verify.json"), encoding="utf-8") as f:
        doc = json.load(f)
    return {"model_error": doc["resimulated_shrink"]["overall"], "torque": doc["torque"]["overall"],
            "worsened_dimensions": doc["resimulated_shrink"]["worsened_dimensions"],
            "fell": [b["fell"] for b in doc["bags"]], "reused": bench_verify if reused else None,
            "verify_wall_s": None if reused else round(time.perf_counter() - t0, 1)}


def _children_cpu() -> float:
    import resource

    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def _part(d: dict, name: str):
    """A family component from a CIML params/interval mapping: 'com_y' is com[1]."""
    return d["com"]["xyz".index(name[-1])] if name.startswith("com_") else d[name]


def ciml_answer(diagnosis: dict, effect: dict, fam: Family) -> dict:
    """CIML's effect of the true type and place (value, std, intervals), or what it said instead."""
    loc = effect.get("joint") or effect.get("link")

    def label(o: dict) -> str:
        return f"{o['type']}@{o.get('joint') or o.get('link') or 'base'}"

    for e in diagnosis.get("effects", []):
        if e["type"] == effect["type"] and (loc is None or loc in (e.get("joint"), e.get("link"))):
            out = {"named": True, "value": [float(_part(e["params"], n)) for n in fam.names],
                   "confidence": e.get("confidence"), "share": e.get("share"),
                   "other_effects": [label(o) for o in diagnosis["effects"] if o is not e]}
            for key in ("interval_95", "interval_68"):  # {"mass": [lo, hi], "com": [[lo, hi] per axis]}
                pairs = [_part(e[key], n) for n in fam.names]
                out[key] = [[float(p[0]) for p in pairs], [float(p[1]) for p in pairs]]
            return out
    return {"named": False, "effects": [label(o) for o in diagnosis.get("effects", [])],
            "unexplained_share": diagnosis.get("unexplained_share")}


def run_sysid(robot, bags: list[str], effect: dict, args) -> tuple[dict, Family]:
    """Read the bags, fit the family of `effect` with mujoco.sysid, intervals; timed from the bags on."""
    import mujoco
    from mujoco import sysid

    t0, c0 = time.perf_counter(), time.process_time()
    logs = [read_log(robot, b) for b in bags]
    lag = effect["type"] == "actuator_lag"
    fam = lag_family(effect) if lag else family_of(effect, robot, logs[0].kp, logs[0].kd)
    spec = nominal_spec(robot, logs[0].kp, logs[0].kd, lag=lag)
    model = spec.compile()
    wins = [w for log in logs for w in windows(model, log, args.window, args.windows)]
    seqs = sysid.ModelSequences("robot", spec, [f"w{i}" for i in range(len(wins))], [w[0] for w in wins],
                                [w[1] for w in wins], [w[2] for w in wins], allow_missing_sensors=True)

    def build(params, base_spec):
        s = base_spec.copy()
        fam.apply(s, params["theta"].value)
        return s.compile()

    params = sysid.ParameterDict({"theta": sysid.Parameter("theta", fam.nominal, fam.lower, fam.upper)})
    residual_fn = sysid.build_residual_fn(models_sequences=[seqs], build_model=build, n_threads=args.threads)
    t_setup = time.perf_counter() - t0
    opt, result = sysid.optimize(params, residual_fn, optimizer="mujoco", verbose=False, max_iters=args.max_iters,
                                 eps=args.fd_step)
    x = opt["theta"].value.copy()
    res, _, _ = residual_fn(x, opt)
    _, half95 = sysid.calculate_intervals(res, result.jac, alpha=T95)
    _, half68 = sysid.calculate_intervals(res, result.jac, alpha=T68)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    r2 = float(np.sum(np.concatenate(res) ** 2))
    return {"value": x.tolist(), "interval_95": [(x - half95).tolist(), (x + half95).tolist()],
            "interval_68": [(x - half68).tolist(), (x + half68).tolist()], "wall_s": round(wall, 1),
            "cpu_s": round(cpu, 1), "iterations": _iterations(result), "setup_s": round(t_setup, 1),
            "windows": len(wins), "window_s": args.window,
            "residual_sum_squares": r2, "mujoco": mujoco.__version__,
            "at_bound": bool(np.any(np.isclose(x, fam.lower) | np.isclose(x, fam.upper)))}, fam


def _iterations(result) -> int | None:
    extras = getattr(result, "extras", None) or {}
    return len(extras.get("objective", [])) or None


def check(robot, logs: list[Log], fam: Family, args) -> dict:
    """Residual sum of squares of the windows with the nominal model and with the true parameter."""
    from mujoco import sysid

    spec = nominal_spec(robot, logs[0].kp, logs[0].kd, lag=fam.kind == "actuator_lag")
    model = spec.compile()
    wins = [w for log in logs for w in windows(model, log, args.window, args.windows)]
    seqs = sysid.ModelSequences("robot", spec, [f"w{i}" for i in range(len(wins))], [w[0] for w in wins],
                                [w[1] for w in wins], [w[2] for w in wins], allow_missing_sensors=True)
    out = {}
    for label, value in (("nominal", None if fam.kind != "actuator_lag" else fam.lower), ("truth", fam.truth)):
        def build(params, base_spec, value=value):
            s = base_spec.copy()
            if value is not None:
                fam.apply(s, value)
            return s.compile()
        params = sysid.ParameterDict({"theta": sysid.Parameter("theta", fam.nominal, fam.lower, fam.upper)})
        fn = sysid.build_residual_fn(models_sequences=[seqs], build_model=build, n_threads=args.threads)
        res, _, _ = fn(params["theta"].value, params)
        out[label] = float(np.sum(np.concatenate(res) ** 2))
    return out


def covers(interval: list, truth: np.ndarray) -> list[bool]:
    lo, hi = np.asarray(interval[0], float), np.asarray(interval[1], float)
    return [bool(x) for x in (lo <= truth) & (truth <= hi)]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--bench", default="out/gap_bench", help="gap-bench output with case_NN bags")
    p.add_argument("--cases", type=int, nargs="+", default=[1, 2, 4, 6])
    p.add_argument("--out", default="out/sysid_compare")
    p.add_argument("--window", type=float, default=0.3, help="window length [s]")
    p.add_argument("--windows", type=int, default=6, help="windows per training bag")
    p.add_argument("--max-iters", type=int, default=30)
    p.add_argument("--threads", type=int, default=1, help="rollout threads of mujoco.sysid")
    p.add_argument("--fd-step", type=float, default=1e-4,
                   help="finite-difference step of the optimiser (its default, 1.5e-8, leaves the payload's CoM "
                        "at its start: the rollouts of CoM 0 and 1e-8 m are bit-identical)")
    p.add_argument("--check", action="store_true", help="also the residual of the nominal and true parameters")
    p.add_argument("--no-ciml", action="store_true", help="skip the CIML diagnosis (sysid only)")
    p.add_argument("--no-resim", action="store_true", help="skip re-simulating each tool's answer (ciml verify)")
    p.add_argument("--probe", action="store_true", help="try sysid.body_inertia_param(InertiaType.Mass) and exit")
    args = p.parse_args()

    from absl import logging as absl_logging

    from ciml_learning.core.robot import load_robot
    from ciml_sim.gapbench import SUITE

    absl_logging.set_verbosity(absl_logging.ERROR)  # one "sensor dimension 24 vs 0" warning per window otherwise
    robot = load_robot()
    if args.probe:
        import mujoco
        from mujoco import sysid

        from ciml_sim.mjcf import build_mjcf

        spec = mujoco.MjSpec.from_string(build_mjcf(robot))
        prm = sysid.body_inertia_param(spec, spec.compile(), "base", sysid.InertiaType.Mass)
        try:
            prm.apply_modifier(spec)
            print("body_inertia_param(InertiaType.Mass): applied")
        except Exception as err:  # noqa: BLE001 - the probe reports whatever fails
            print(f"body_inertia_param(InertiaType.Mass) on mujoco {mujoco.__version__}: {type(err).__name__}: "
                  f"{str(err).splitlines()[0]}")
        return 0
    os.makedirs(args.out, exist_ok=True)
    path = os.path.join(args.out, "sysid_compare.json")
    doc = {"args": vars(args), "cases": {}}
    if os.path.isfile(path):
        with open(path, encoding="utf-8") as f:
            doc["cases"] = json.load(f).get("cases", {})
    for case in args.cases:
        spec_case = SUITE[case - 1]
        if len(spec_case["effects"]) != 1 or "reference_effects" in spec_case:
            raise SystemExit(f"case {case}: one effect per case here")
        effect = spec_case["effects"][0]
        case_dir = os.path.join(args.bench, f"case_{case:02d}")
        bags = sorted(os.path.join(case_dir, d) for d in os.listdir(case_dir) if d.startswith("train_"))
        row = {"effect": effect, "load_before": os.getloadavg()[0]}
        row["sysid"], fam = run_sysid(robot, bags, effect, args)
        row.update({"truth": fam.truth.tolist(), "names": fam.names, "told": fam.told})
        if not args.no_ciml:
            diagnosis, wall, cpu = run_ciml(case_dir, os.path.join(args.out, f"case_{case:02d}_ciml"))
            row["ciml"] = {**ciml_answer(diagnosis, effect, fam), "wall_s": round(wall, 1), "cpu_s": round(cpu, 1),
                           "diagnosis_time_s": diagnosis.get("time_s")}
            if row["ciml"]["named"]:
                row["ciml"]["covers_95"] = covers(row["ciml"]["interval_95"], fam.truth)
                row["ciml"]["covers_68"] = covers(row["ciml"]["interval_68"], fam.truth)
        if args.check:
            logs = [read_log(robot, b) for b in bags]
            row["check"] = check(robot, logs, fam, args)
            print(f"case {case}: residual nominal {row['check']['nominal']:.4g}, truth {row['check']['truth']:.4g}",
                  flush=True)
        row["sysid"]["covers_95"] = covers(row["sysid"]["interval_95"], fam.truth)
        row["sysid"]["covers_68"] = covers(row["sysid"]["interval_68"], fam.truth)
        if not args.no_resim:
            import yaml

            from ciml_learning.diagnosis.files import IDENTIFIED_SCENARIO

            oracle = os.path.join(args.bench, "answers", f"case_{case:02d}.yaml")
            sysid_dir = os.path.join(args.out, f"case_{case:02d}_sysid")
            os.makedirs(sysid_dir, exist_ok=True)
            with open(os.path.join(sysid_dir, IDENTIFIED_SCENARIO), "w", encoding="utf-8") as f:
                yaml.safe_dump(sysid_scenario(effect, fam, row["sysid"]["value"]), f, sort_keys=False)
            row["sysid"]["resim"] = run_verify(case_dir, sysid_dir, oracle, os.path.join(sysid_dir, "verify"))
            if not args.no_ciml:
                ciml_dir = os.path.join(args.out, f"case_{case:02d}_ciml")
                row["ciml"]["resim"] = run_verify(case_dir, ciml_dir, oracle, os.path.join(args.out,
                                                                                          f"case_{case:02d}_ciml_verify"))
        row["load_after"] = os.getloadavg()[0]
        doc["cases"][str(case)] = row
        with open(path, "w", encoding="utf-8") as f:
            json.dump(doc, f, indent=1)
        keys = ("value", "interval_95", "wall_s", "cpu_s")
        print(json.dumps({"case": case, "truth": row["truth"],
                          "ciml": {k: row.get("ciml", {}).get(k) for k in keys},
                          "sysid": {k: row["sysid"][k] for k in keys},
                          "resim_gap": {tool: row.get(tool, {}).get("resim", {}).get("model_error")
                                        for tool in ("ciml", "sysid")}}), flush=True)
    print(f"sysid_compare: {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
