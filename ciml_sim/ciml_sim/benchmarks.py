"""Benchmarks of ciml_sim (`ciml bench`, registered in setup.py under the `ciml.benchmarks` entry points).

Each function runs with its defaults as the benchmark's settings and returns one JSON-able dict.
Compare numbers from one run only: the machines are shared and noisy.
"""
from __future__ import annotations

import copy
import os
import random
import shutil
import tempfile
import time

import mujoco
import numpy as np
import rclpy
from ciml_msgs.msg import TorqueCommand
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState

from ciml_control.standing import StandingController
from ciml_learning.cli.benchmarks import per_sample_floor
from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import load_robot
from ciml_learning.diagnosis.run import diagnose
from ciml_learning.logs.bagio import BagWriter
from ciml_learning.ros.ros_common import COMMAND_QOS, SENSOR_QOS

from . import live_bench
from .bridge_node import MujocoBridge
from .plant import Plant
from .recorder import CONTROL_RATE, PHYSICS_STEPS_PER_TICK, run_headless
from .scenario import load_scenario, resolve_scenario, scenario_dir


def sim_headless_speed() -> dict:
    """Headless simulation speed, trot_35 on default_gap (speed_benchmark)."""
    return speed_benchmark(motion="trot_35", duration=4.0)


def speed_benchmark(motion: str = "trot_35", duration: float = 4.0, scenario: str = "default_gap") -> dict:
    """Headless real-time factor at 1 kHz physics with the controller (target ≥ 20×),
    without and with bag writing, and where the wall time goes (`compiled_s`: the ticks
    run by joint_loop.closed_loop).

    A short warm-up run first loads the compiled kernels (numba's on-disk cache; compiled
    on the very first use after an install) — a once-per-process cost reported as
    `process_warmup_s`, not in the factors. `real_time_factor`: a first run of the motion
    (its reference sampled as it goes); `real_time_factor_reference_cached`: the same run
    again (the reference grid cached, as for every further run of the motion in a
    process); the recording (bag with ground truth, zstd) also runs with the cached grid.
    `cpu_real_time_factor_reference_cached`: the cached run's simulated time per second of
    this process's CPU time — on a shared machine less disturbed by other load than wall time.
    `bare_mj_step_real_time_factor`: the floor, MuJoCo's own step of the same model from the
    standing state (`over_bare_mj_step`: each factor against it).
    """
    robot = load_robot()
    scen = resolve_scenario(scenario, robot)
    out: dict = {"motion": motion, "scenario": scenario, "sim_duration_s": duration, "physics_rate_hz": 1000,
                 "target_real_time_factor": 20.0}
    t0 = time.perf_counter()
    run_headless(robot, scen, "stand", 0.02, seed=0, progress=False, settle_time=0.02)
    with tempfile.TemporaryDirectory() as tmp:
        with BagWriter(f"{tmp}/bag") as w:  # the message templates too
            run_headless(robot, scen, "stand", 0.02, seed=0, writer=w, progress=False, settle_time=0.02)
    out["process_warmup_s"] = round(time.perf_counter() - t0, 3)
    r = run_headless(robot, scen, motion, duration, seed=0, progress=False)
    sim = len(r.t) / CONTROL_RATE
    loop_wall = sum(r.timings.values())
    out["real_time_factor"] = round(sim / r.wall_time, 2)
    out["real_time_factor_loop_only"] = round(sim / loop_wall, 2)
    out["wall_per_sim_second_s"] = {k: round(v / sim, 4) for k, v in r.timings.items()}
    out["controller"] = r.controller
    out["fell"] = r.fell
    cpu0 = time.process_time()
    r1 = run_headless(robot, scen, motion, duration, seed=0, progress=False)
    cpu = time.process_time() - cpu0
    out["real_time_factor_reference_cached"] = round(len(r1.t) / CONTROL_RATE / r1.wall_time, 2)
    out["cpu_real_time_factor_reference_cached"] = round(len(r1.t) / CONTROL_RATE / cpu, 2)
    with tempfile.TemporaryDirectory() as tmp:
        with BagWriter(f"{tmp}/bag", compression="zstd") as w:
            r2 = run_headless(robot, scen, motion, duration, seed=0, writer=w, progress=False)
    out["real_time_factor_recording_with_ground_truth"] = round(len(r2.t) / CONTROL_RATE / r2.wall_time, 2)
    out["recording_writer_s_per_sim_second"] = round(r2.timings["writer_s"] * CONTROL_RATE / len(r2.t), 4)
    # the plant alone (physics + joint loop + sensors), holding a standing command
    plant = Plant(robot, scen, seed=0)
    nj = robot.n_joints
    q0 = plant.standing_configuration()
    plant.set_command(np.zeros(nj), q0[7:], np.zeros(nj), np.full(nj, 300.0), np.full(nj, 8.0))
    t0 = time.perf_counter()
    n = 1000
    for _ in range(n):
        plant.measure()
        plant.step(PHYSICS_STEPS_PER_TICK)
    wall = time.perf_counter() - t0
    out["plant_only_real_time_factor"] = round(n * PHYSICS_STEPS_PER_TICK * 1e-3 / wall, 2)
    out["plant_us_per_physics_step"] = round(wall / (n * PHYSICS_STEPS_PER_TICK) * 1e6, 2)
    # the floor: bare mj_step of the same model from the standing state just reached (the
    # plant's last torques held in ctrl; no joint loop, sensors or controller), in Python
    data = copy.copy(plant.data)
    steps = n * PHYSICS_STEPS_PER_TICK
    t0 = time.perf_counter()
    for _ in range(steps):
        mujoco.mj_step(plant.model, data)
    bare = steps * plant.model.opt.timestep / (time.perf_counter() - t0)
    out["bare_mj_step_real_time_factor"] = round(bare, 2)
    out["over_bare_mj_step"] = {k: round(out[k] / bare, 3) for k in (
        "real_time_factor", "real_time_factor_reference_cached", "plant_only_real_time_factor")}
    return out


def scaling(sizes: str = "10000,100000,1000000", stages: str = "extraction,diagnosis,train_lwpr,train_sgpr",
            motion: str = "trot_35", scenario: str = "default_gap", bag_samples: str = "10000", jobs: str = "1",
            stage_limit_s: str = "900", bag_dir: str = "") -> dict:
    """Wall time, CPU time and peak RSS of extraction, diagnosis and training against the log's
    size N, each (stage, N) in a fresh process, with the fitted exponents b of a·N^b (issue 30
    item 1; ciml_sim.scaling, whose docstring says how the logs are simulated). Options
    (ciml bench --set NAME=VALUE): sizes comma-separated; stages, of extraction, diagnosis,
    train_lwpr, train_sgpr; motion and scenario of the recordings; bag_samples per recorded bag;
    jobs of training; stage_limit_s: a size whose predicted time exceeds it is skipped; bag_dir:
    keep the recorded bags there (and reuse them) instead of a temporary folder."""
    from .scaling import scaling_benchmark

    return scaling_benchmark(sizes, stages, motion, scenario, int(bag_samples), int(jobs), float(stage_limit_s),
                             bag_dir)


def live_graph_rates() -> dict:
    """The launch file's whole graph for 60 s: rates, CPU, exit codes (ciml_sim.live_bench; it
    starts this package's launch file, so the benchmark is registered here)."""
    return live_bench.graph_rates(duration=60.0)


def live_graph_memory() -> dict:
    """The launch file's graph in lockstep (a healthy trot whatever the machine's load) for 10
    minutes: resident memory of every process at the start and the end of the window (the
    learner writes and the server swaps snapshots all along), rates."""
    return live_bench.graph_rates(duration=600.0, layouts=("lockstep",))


def live_online_learning(seeds: str = "0,1,2,3,4", scenarios: str = "default_gap", duration: str = "600",
                         period: str = "60", baseline_seeds: str = "", robot: str = "hyq", launch: str = "",
                         plot: str = "") -> dict:
    """Online learning on the live graph, with and without, per seed and scenario, per period
    (ciml_sim.live_bench.online_learning_runs); `plot`: also a PNG of the effort per period.
    Options (ciml bench --set NAME=VALUE): seeds, baseline_seeds (the runs without learning;
    default: seeds; `none`: no such run, e.g. to add runs to a baseline measured before; seeds
    `none`: only runs without learning, e.g. with launch=model:=DIR) and
    scenarios comma-separated (a scenario: a shipped name or a YAML file),
    duration and period in simulated seconds, robot (a shipped name or a profile; the scenarios
    must be its own, e.g. go1_gap for go1), launch (more launch arguments, NAME:=VALUE
    comma-separated, e.g. learner_nice:=0)."""
    def ints(name: str, text: str) -> tuple[int, ...]:
        if text == "none":
            return ()
        try:
            return tuple(int(s) for s in text.split(","))
        except ValueError:
            raise CimlError(f"{name} must be comma-separated integers or none, got {text!r}") from None

    baseline = ints("baseline_seeds", baseline_seeds) if baseline_seeds else None
    result = live_bench.online_learning_runs(ints("seeds", seeds), tuple(scenarios.split(",")), float(duration),
                                             float(period), baseline, robot,
                                             dict(a.split(":=", 1) for a in launch.split(",")) if launch else None)
    if plot:
        live_bench.plot_learning_runs(result, plot)
    return result


def rate_benchmark(seconds: float = 8.0, publish_rate: float = 250.0) -> dict:
    """The bridge with ROS I/O: it publishes its sensors and a commander node sends a
    standing TorqueCommand back at 250 Hz (one process, own DDS domain, loopback only).
    Reports the achieved physics rate (target 1000 Hz of simulation time per wall second)
    and the tick-period error (p50/p99) of the publish timer."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random.SystemRandom().randint(1, 101))
    try:
        bridge = MujocoBridge(context=ctx, parameter_overrides=[Parameter("publish_rate", value=publish_rate)])
        robot = bridge.robot
        q0 = bridge.plant.standing_configuration()
        c = StandingController(robot).compute(q0, np.ones(robot.n_feet, dtype=bool))
        arrays = cv.TorqueCommandArrays(0, c.feedforward, c.feedback_linearization, c.q_target, c.qd_target, c.kp, c.kd)
        commander = rclpy.create_node("bench_commander", context=ctx)
        pub = commander.create_publisher(TorqueCommand, topics.TORQUE_COMMAND, COMMAND_QOS)
        received = [0]
        commander.create_subscription(JointState, topics.JOINT_STATES,
                                      lambda m: received.__setitem__(0, received[0] + 1), SENSOR_QOS)
        commander.create_timer(0.004, lambda: pub.publish(cv.torque_command_msg(robot, 0, arrays)))
        ex = SingleThreadedExecutor(context=ctx)
        ex.add_node(bridge)
        ex.add_node(commander)
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end:  # discovery, first commands
            ex.spin_once(timeout_sec=0.01)
        wall0, steps0, ticks0, cmd0 = time.monotonic(), bridge.physics_steps, bridge.n_ticks, bridge.commands_received
        sim0 = bridge.plant.time
        while time.monotonic() < wall0 + seconds:
            ex.spin_once(timeout_sec=0.01)
        wall = time.monotonic() - wall0
        p = np.asarray(list(bridge.tick_periods)[-(bridge.n_ticks - ticks0):])
        nominal = bridge.steps_per_sample * 1e-3
        err = np.abs(p - nominal) * 1e3
        base_z = float(bridge.plant.data.qpos[2])
        out = {
            "publish_rate_hz": 1000.0 / bridge.steps_per_sample,
            "target_physics_rate_hz": 1000.0,
            "achieved_physics_rate_hz": round((bridge.physics_steps - steps0) / wall, 1),
            "sim_time_per_wall_second": round((bridge.plant.time - sim0) / wall, 3),
            "tick_period_nominal_ms": nominal * 1e3,
            "tick_period_p50_ms": round(float(np.percentile(p, 50)) * 1e3, 3),
            "tick_period_error_p50_ms": round(float(np.percentile(err, 50)), 3),
            "tick_period_error_p99_ms": round(float(np.percentile(err, 99)), 3),
            "realtime_overruns": int(bridge.health.counts.get("realtime_overruns", 0)),
            "commands_received_per_s": round((bridge.commands_received - cmd0) / wall, 1),
            "joint_states_received": received[0],
            "stale_command_damping": int(bridge.health.counts.get("stale_command_damping", 0)),
            "still_standing": base_z > 0.5,
            "seconds": seconds,
        }
        return out
    finally:
        rclpy.try_shutdown(context=ctx)


def diagnosis_benchmark(n_samples: int = 50_000, seconds: float = 20.0, motion: str = "walk_35",
                        jobs: int = 1) -> dict:
    """Diagnosis of n_samples (250 Hz) end to end: bag reading, filtering, extraction, regressors,
    selection, bootstrap, report. One simulated bag of the default gap scenario (this package's
    recorder, not timed) is given repeatedly, 80 % as identification and 20 % as held-out bags.
    jobs: processes reading the bags (`ciml diagnose --jobs`, whose default −1 is every core; 1 keeps
    the figures comparable with earlier runs)."""
    robot = load_robot()
    scenario = load_scenario(os.path.join(scenario_dir(), "default_gap.yaml"), robot)
    tmp = tempfile.mkdtemp(prefix="ciml_diag_bench_")
    try:
        bag = os.path.join(tmp, "bag")
        with BagWriter(bag) as w:
            run_headless(robot, scenario, motion, seconds, 1, writer=w, ground_truth=False, progress=False)
        per_bag = int(round(seconds * 250))
        copies = max(2, int(round(n_samples / per_bag)))
        n_ho = max(1, copies // 5)
        t0, c0 = time.perf_counter(), time.process_time()
        result = diagnose(robot, [bag] * (copies - n_ho), [bag] * n_ho, os.path.join(tmp, "out"), progress=False,
                          jobs=jobs)
        elapsed, cpu = time.perf_counter() - t0, time.process_time() - c0
        floor = per_sample_floor()
        return {"samples": copies * per_bag, "jobs": jobs,
                "us_per_sample": round(1e6 * elapsed / (copies * per_bag), 1), **floor,
                "over_floor": round(1e6 * elapsed / (copies * per_bag) / floor["floor_us_per_sample"], 1),
                "target_over_floor": 40.0,
                "valid_samples": result["data"]["samples"] + result["data"]["heldout_samples"],
                "diagnosis_s": round(elapsed, 2), "diagnosis_cpu_s": round(cpu, 2), "target_s": 120.0,
                "effects": [e["type"] for e in result["effects"]]}
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
