"""Benchmarks of the live graph started from its launch file (`ciml bench`; docs/LIVE_GRAPH.md).

Both benchmarks start this package's `launch/closed_loop.launch.yaml` with the same launcher as
`ciml launch` (ciml_learning.ros.launcher; the file and the executables are found by name in
the ament index) and watch the graph with ciml_learning.ros.graph_probe.GraphProbe in this
process, on a private DDS domain (loopback only):

- `live_graph_rates`: per topic the receive rate and the period p50/p99 and jitter
  (p99 of |period − nominal|) measured at the probe; the QP-failure fraction from
  id_controller's /diagnostics counters and the fraction of MODE_DAMPING commands; the
  resident memory (VmRSS of /proc/<pid>/status) of every node at the start and the end
  of the window; the lowest measured base height (/base_state).
- `live_online_learning` (online_learning_runs): the feedback effort of the paper's Tables
  I–II, ‖K_p(qᵈ − q) + K_d(q̇ᵈ − q̇) + u_fb,lin‖ per command (rollback.feedback_effort, the PD
  part on the joint sample the command was computed for), RMS per period of many seeded runs
  with and without online learning, falls and the learning chain's counters per period.
The probe itself costs CPU on the same machine: rates measured here are a lower bound.
"""
from __future__ import annotations

import os
import random
import sys
import tempfile
import time

import numpy as np

from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.ros.graph_probe import GraphProbe, cpu_seconds, period_stats
from ciml_learning.ros.realtime import rss_mb

LAUNCH_PACKAGE = "ciml_sim"
LAUNCH_FILE = "closed_loop.launch.yaml"

NOMINAL_RATES_HZ = {topics.JOINT_STATES: 250.0, topics.BASE_STATE: 250.0, topics.CONTACT_STATE: 250.0,
                    topics.CLOCK: 250.0, topics.TORQUE_COMMAND: 250.0, topics.FILTERED_STATE: 250.0,
                    topics.MODEL_ERROR_MEASURED: 250.0, topics.REFERENCE: 250.0,
                    topics.MODEL_ERROR_PREDICTED: 250.0}
"""Configured rates of the shipped launch file's defaults (bridge publish_rate, reference rate)."""
MEASURED_RATES = (topics.JOINT_STATES, topics.BASE_STATE, topics.TORQUE_COMMAND, topics.FILTERED_STATE,
                  topics.MODEL_ERROR_PREDICTED)
"""What live_graph_rates times: the sample, the command, the filtered state and the prediction. The
probe shares the machine (each topic it reads costs ~100 µs of CPU per message), so it reads no more."""
MAIN_TOPIC = {"mujoco_bridge": topics.JOINT_STATES, "reference_generator": topics.REFERENCE,
              "id_controller": topics.TORQUE_COMMAND, "model_server": topics.MODEL_ERROR_PREDICTED,
              "state_filter": topics.FILTERED_STATE, "error_extractor": topics.MODEL_ERROR_MEASURED,
              "online_learner": topics.MODEL_ERROR_MEASURED}
"""The message each node handles once per cycle (its CPU per cycle = CPU time / these messages)."""


PROBE_PRIORITY = 5
"""SCHED_FIFO priority of live_graph_rates' probe (and the live tests'), below every real-time
node's (control path 50, model server 20): a normally scheduled probe on a machine whose two
cores carry ~1.4 cores of graph times its own wait for the CPU (~4 ms p99 on every topic, even
/joint_states published with 0.1 ms of tick error), not the graph's delivery."""

EFFORT_PROBE_NICE = 19
"""Nice level of live_online_learning's probe threads. The probe decodes every /joint_states and
/torque_command sample in Python to compute the feedback effort; normally scheduled, it took about
a quarter of a core from a 2-core machine the graph already fills, and the learner (nice 10) lost a
quarter to a half of the filtered states while a user's own run of the same graph lost none. The
effort is a sample of the commands either way (results/LIVE_GRAPH.md)."""
FALL_HEIGHT = 0.3
"""[m] base height below which HyQ lies on its trunk (standing 0.61 m; ciml_sim.recorder's fall rule)."""
FALL_RATIO = 0.5
"""live_online_learning's fall: the base below this fraction of the robot's standing height
(physical_bounds; HyQ 0.31 m, the learning gate's own rule)."""


def _growth(start: float | None, end: float | None) -> float | None:
    return None if start is None or end is None else round(end - start, 1)


def _rate(start: float | None, end: float | None, seconds: float) -> float | None:
    return None if start is None or end is None else round((end - start) / seconds, 3)


def _private_domain() -> None:
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(random.SystemRandom().randint(1, 101)))


def _load_average() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def start_graph(arguments: dict[str, str], log_dir: str, only: list[str] | None = None):
    """The shipped launch file's nodes started by the launcher (output to log_dir/<node>.log)."""
    from ciml_learning.ros.launch_file import find_package_share, load
    from ciml_learning.ros.launcher import Launcher

    path = os.path.join(find_package_share(LAUNCH_PACKAGE), "launch", LAUNCH_FILE)
    desc = load(path, arguments)
    out = open(os.path.join(log_dir, "launch.log"), "w", encoding="utf-8")
    launcher = Launcher(desc, out=out, log_dir=log_dir)
    launcher.start(only)
    return launcher, out


LAYOUTS = {
    "free_running": {"lockstep": "false"},
    "lockstep": {"lockstep": "true"},
    "free_running_processes": {"lockstep": "false", "containers": ""},
}
"""The runs of `live_graph_rates`: the launch file's containers against the wall clock (the
target: a real robot's loop), the same in lockstep (the file's default), and every node in its
own process against the wall clock (the layout ros2 launch starts), for comparison."""


def graph_rates(duration: float = 60.0, warmup: float = 10.0, arguments: dict[str, str] | None = None,
                startup_timeout: float = 300.0, layouts: tuple[str, ...] = tuple(LAYOUTS)) -> dict:
    """`live_graph_rates`: the shipped graph (trot on the default gap, online learning) for
    `duration` seconds after the controller commands torques and `warmup` seconds more, once per
    layout of LAYOUTS, in one benchmark (numbers of one run are comparable; machines are noisy).
    Free-running, wall-clock rates are the target; in lockstep, every sample gets its command
    and simulated time follows the graph (rates per simulated second, achieved real-time factor)."""
    _private_domain()
    return {name: _rates_run({**LAYOUTS[name], **(arguments or {})}, duration, warmup, startup_timeout)
            for name in layouts}


def _rates_run(arguments: dict[str, str], duration: float, warmup: float, startup_timeout: float) -> dict:
    rate_topics = {t: topics.TYPES[t] for t in MEASURED_RATES}
    with tempfile.TemporaryDirectory(prefix="ciml_live_") as tmp:
        args = {"model_dir": os.path.join(tmp, "online_model"), **(arguments or {})}
        probe = GraphProbe(rate_topics, priority=PROBE_PRIORITY)
        launcher, out = start_graph(args, tmp)
        result: dict = {"arguments": args, "load_average_start": _load_average(), "probe_scheduling": probe.scheduling}
        try:
            if not probe.wait_for(lambda: probe.first_torque_time is not None, startup_timeout):
                raise CimlError(f"the graph sent no torque command within {startup_timeout:g} s")
            result["startup_s"] = round(probe.first_torque_time - min(n.started for n in launcher.nodes), 1)
            time.sleep(warmup)
            pids = {n.label: n.proc.pid for n in launcher.nodes}
            rss_start = {k: rss_mb(p) for k, p in pids.items()}
            cpu_start = {k: cpu_seconds(p) for k, p in pids.items()}
            with probe.lock:
                probe.base_z.clear()
            probe.recording = True
            t0 = time.monotonic()
            # resident memory through the window: bounded means flat in its second half
            step = max(duration / 10.0, 1.0)
            rss_series: dict[str, list] = {k: [] for k in pids}
            while time.monotonic() < t0 + duration:
                time.sleep(min(step, max(t0 + duration - time.monotonic(), 0.0)))
                for k, p in pids.items():
                    rss_series[k].append(rss_mb(p))
            probe.recording = False
            wall = time.monotonic() - t0
            rss_end = {k: rss_mb(p) for k, p in pids.items()}
            cpu_end = {k: cpu_seconds(p) for k, p in pids.items()}
            result["load_average_end"] = _load_average()
            result["window_s"] = round(wall, 1)
            result["topics"] = {t: period_stats(np.asarray(probe.receipts.get(t, [])), hz)
                                for t, hz in NOMINAL_RATES_HZ.items() if t in MEASURED_RATES}
            qp = probe.counter("id_controller", "qp_failures") or 0.0
            cmds = probe.counter("id_controller", "commands")
            result["qp_failure_fraction"] = round(qp / cmds, 4) if cmds else None
            result["damping_command_fraction"] = round(probe.n_damping / max(probe.n_commands, 1), 4)
            # since the controller's start: steps that held a late /reference, damped a dead one, gated ε
            result["controller_counts"] = {k: probe.counter("id_controller", k) for k in
                                           ("reference_held", "stale_reference", "epsilon_gated", "epsilon_clipped")}
            result["rss_mb"] = {k: {"start": rss_start[k], "end": rss_end[k],
                                    "growth": _growth(rss_start[k], rss_end[k]),
                                    "growth_second_half": _growth(rss_series[k][len(rss_series[k]) // 2 - 1],
                                                                  rss_end[k]),
                                    "series": rss_series[k]} for k in pids}
            # CPU demand of each node: 1.0 = one core busy the whole window
            result["cpu_cores"] = {k: _rate(cpu_start[k], cpu_end[k], wall) for k in pids}
            result["cpu_cores_total"] = round(sum(v for v in result["cpu_cores"].values() if v), 3)
            # CPU per cycle [ms]: what 250 Hz costs a process, less dependent on other load than
            # rates; a node alone per message it handles, a container per joint sample
            result["cpu_ms_per_cycle"] = {
                k: round(1e3 * c * wall / len(probe.receipts[MAIN_TOPIC.get(k, topics.JOINT_STATES)]), 3)
                for k, c in result["cpu_cores"].items()
                if c is not None and probe.receipts.get(MAIN_TOPIC.get(k, topics.JOINT_STATES))}
            with probe.lock:
                z = [v for _t, v in probe.base_z]
            with probe.lock:
                sim = probe.base_z[-1][0] - probe.base_z[0][0] if len(probe.base_z) > 1 else 0.0
            result["simulated_s"] = round(sim, 2)
            result["real_time_factor_achieved"] = round(sim / wall, 3)
            # rates on the simulation's own clock: 250 when every sample gets its command
            result["per_simulated_second"] = {
                t: round(len(probe.receipts.get(t, [])) / sim, 1) if sim > 0 else None
                for t in (topics.JOINT_STATES, topics.TORQUE_COMMAND, topics.FILTERED_STATE,
                          topics.MODEL_ERROR_PREDICTED)}
            # rates and jitter as the nodes publish them (PublishPeriods, 10 s windows): the worst window
            with probe.lock:
                result["as_published"] = {
                    f"/{topic}": {"windows": len(w), "rate_hz_min": min(r for r, _ in w),
                                  "jitter_p99_ms_max": max(j for _, j in w)}
                    for topic, w in probe.published.items() if w}
            result["base_height_min_m"] = round(min(z), 3) if z else None
            result["fell"] = bool(z) and min(z) < FALL_HEIGHT
            bridge = {k: probe.counter("mujoco_bridge", k) for k in
                      ("achieved_physics_rate_hz", "tick_period_error_p99_ms", "realtime_overruns")}
            result["bridge_diagnostics"] = bridge
        finally:
            result["shutdown_rc"] = launcher.stop()
            result["exit_codes"] = {n.label: n.returncode for n in launcher.nodes}
            out.close()
            probe.close()
        tails = {}
        for n in launcher.nodes:
            try:
                with open(os.path.join(tmp, f"{n.label}.log"), encoding="utf-8") as f:
                    text = f.read()
            except OSError:
                continue
            if "Traceback" in text or n.returncode != 0:
                tails[n.label] = text[-2000:]
        result["tracebacks"] = tails
    return result


LEARNING_COUNTERS = {
    "state_filter": ("states_valid", "states_contact_change", "states_bridged_gap_window", "joint_samples_filled",
                     "filter_restarts"),
    "online_learner": ("samples_received", "samples_lost", "samples_learned", "held_back_samples", "invalid_samples",
                       "paused_fall", "paused_tracking_error", "paused_no_reference", "paused_recovering",
                       "paused_target_beyond_bounds", "snapshots_accepted",
                       "snapshots_refused_too_few_samples", "snapshots_refused_not_better_than_nominal",
                       "outputs_served", "learn_us_mean"),
    "model_server": ("model_swaps", "models_superseded", "swap_hold_ms", "load_ms", "rollbacks", "refused_models",
                     "predictions"),
    "id_controller": ("commands", "rollbacks", "rollbacks_worse_than_before", "rollback_detect_ms", "models_judged",
                      "models_unjudged", "epsilon_gated",
                      "qp_failures", "reference_held", "stale_reference", "prediction_behind_reference",
                      "prediction_lag_p50_ms", "prediction_lag_p99_ms", "reference_lag_mean_ms",
                      "reference_lag_p99_ms"),
}
"""The counters `live_online_learning` samples from /diagnostics at the end of every period."""


def online_learning_runs(seeds: tuple[int, ...] = (0, 1, 2, 3, 4), scenarios: tuple[str, ...] = ("default_gap",),
                         duration: float = 600.0, period: float = 60.0, baseline_seeds: tuple[int, ...] | None = None,
                         robot: str = "hyq", launch: dict[str, str] | None = None,
                         startup_timeout: float = 300.0) -> dict:
    """`live_online_learning`: per scenario, one run of the shipped graph with online learning per
    seed of `seeds` and one without per seed of `baseline_seeds` (default: the same; the launch
    file's `seed` is the sensor noise's), `duration` seconds of simulated trot each (lockstep: the
    graph's own pace on a loaded machine). Per `period` of simulated time: the RMS feedback effort
    (feedback_effort), the lowest base height and the learning chain's counters
    (LEARNING_COUNTERS); a fall ends a run. Summary (learning_summary): falls, the effort cut per
    period, and per run with learning its cut in its last period and its worst period against the
    runs without, next to their noise (their spread between seeds). `robot`: the launch file's
    robot argument (a shipped name or a profile); its scenarios must name it. `launch`: more
    launch arguments for every run (e.g. learner_nice)."""
    from ciml_learning.core.profile import load_profile

    description = load_profile(robot).robot()
    _private_domain()
    baseline_seeds = seeds if baseline_seeds is None else baseline_seeds
    out: dict = {"robot": robot, "launch": dict(launch or {}), "seeds": list(seeds),
                 "baseline_seeds": list(baseline_seeds), "scenarios": list(scenarios), "duration_s": duration,
                 "period_s": period, "load_average_start": _load_average(), "runs": []}
    for scenario in scenarios:
        for online, run_seeds in ((False, baseline_seeds), (True, seeds)):
            for seed in run_seeds:
                args = {**(launch or {}), "online_learning": "true" if online else "false", "seed": str(seed),
                        "scenario": scenario, "robot": robot}
                run = _effort_run(description, args, duration, period, startup_timeout)
                out["runs"].append({"scenario": scenario, "seed": seed, "online": online, **run})
                print(f"[bench] live_online_learning {scenario} seed {seed} online={online}: effort per period "
                      f"{[p['effort_rms_nm'] for p in run['periods']]}, fell {run['fell']}", file=sys.stderr,
                      flush=True)
    out["summary"] = learning_summary(out["runs"])
    out["load_average_end"] = _load_average()
    return out


def learning_summary(runs: list[dict]) -> dict:
    """Falls and effort cuts of online_learning_runs' runs (see there), per scenario: runs with
    learning against the mean of the runs without, period by period."""
    summary: dict = {"runs_with_learning": sum(r["online"] for r in runs),
                     "falls_with_learning": sum(r["fell"] for r in runs if r["online"]),
                     "falls_without_learning": sum(r["fell"] for r in runs if not r["online"]), "scenarios": {}}
    for scenario in dict.fromkeys(r["scenario"] for r in runs):
        def efforts(online: bool) -> list[list[float]]:
            return [[np.nan if p["effort_rms_nm"] is None else p["effort_rms_nm"] for p in r["periods"]] for r in runs
                    if r["scenario"] == scenario and r["online"] == online]

        without, with_ = efforts(False), efforts(True)
        n = min((len(e) for e in without + with_), default=0)
        if not without or not n:
            continue
        base = np.array([e[:n] for e in without], dtype=float)
        mean, noise = base.mean(axis=0), base.std(axis=0)
        learned = np.array([e[:n] for e in with_], dtype=float) if with_ else np.zeros((0, n))
        summary["scenarios"][scenario] = {
            "per_period": [{"t_end_s": runs[0]["periods"][k]["t_end_s"] if runs[0]["periods"] else None,
                            "effort_without_nm": round(float(mean[k]), 2),
                            "effort_with_nm": round(float(learned[:, k].mean()), 2) if len(learned) else None,
                            "cut_pct": round(100.0 * (1.0 - learned[:, k].mean() / mean[k]), 1) if len(learned)
                            else None,
                            "noise_nm": round(float(noise[k]), 2)} for k in range(n)],
            "last_period_cut_pct_per_run": [round(100.0 * (1.0 - e[-1] / mean[-1]), 1) for e in learned],
            "worst_period_excess_over_noise_nm": [round(float(np.max(e - mean - noise)), 2) for e in learned],
            "periods_compared": n}
    return summary


def plot_learning_runs(result: dict, path: str) -> None:
    """Per scenario, the effort per period of every run without (grey) and with (blue) learning (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ciml_learning.core.fileio import atomic_write_bytes

    scenarios = result["scenarios"]
    fig, axes = plt.subplots(1, len(scenarios), figsize=(6 * len(scenarios), 4), squeeze=False)
    for ax, scenario in zip(axes[0], scenarios):
        for r in result["runs"]:
            if r["scenario"] != scenario:
                continue
            t = [p["t_end_s"] for p in r["periods"]]
            e = [p["effort_rms_nm"] for p in r["periods"]]
            ax.plot(t, e, "o-" if r["online"] else "s--", color="tab:blue" if r["online"] else "0.6", lw=1, ms=3)
            if r["fell"]:
                ax.plot(t[-1:], e[-1:], "rx", ms=10)
        ax.set_title(f"{scenario}: blue with online learning, grey without")
        ax.set_xlabel("simulated time [s] (end of period)")
        ax.set_ylabel("RMS feedback effort per period [Nm]")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    import io

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_write_bytes(path, buf.getvalue())


SLICE = 5.0
"""[s] of simulated time per entry of a period's `effort_rms_slices_nm` (a model is served ≥ 6 s)."""


def _slice_rms(timed: list[tuple[float, float]], t0: float, start: float, length: float) -> list[float | None]:
    """RMS effort per `length` seconds from `start` (seconds after t0) of (t, effort) samples."""
    bins: dict[int, list[float]] = {}
    for t, e in timed:
        bins.setdefault(int((t - t0 - start) // length), []).append(e)
    n = max(bins, default=-1) + 1
    return [round(float(np.sqrt(np.mean(np.square(bins[k])))), 2) if k in bins else None for k in range(n)]


def _effort_run(robot, arguments: dict[str, str], duration: float, period: float, startup_timeout: float) -> dict:
    from ciml_learning.core.physical_bounds import physical_bounds

    fall = FALL_RATIO * physical_bounds(robot).standing_height
    with tempfile.TemporaryDirectory(prefix="ciml_live_") as tmp:
        args = {"model_dir": os.path.join(tmp, "online_model"), **arguments}
        probe = GraphProbe(effort_robot=robot, nice=EFFORT_PROBE_NICE)
        launcher, log = start_graph(args, tmp)
        periods: list[dict] = []
        fell_at = None
        t_wall = time.monotonic()
        try:
            if not probe.wait_for(lambda: probe.first_torque_stamp is not None, startup_timeout):
                raise CimlError(f"the graph sent no torque command within {startup_timeout:g} s")
            assert probe.first_torque_stamp is not None
            t0 = probe.first_torque_stamp * 1e-9
            deadline = time.monotonic() + duration * 10 + 60  # lockstep on a loaded machine: sim time runs slower
            start = 0
            while len(periods) * period < duration and time.monotonic() < deadline:
                end = (len(periods) + 1) * period
                probe.wait_for(lambda: probe.sim_time() - t0 >= end or probe.lowest_z() < fall,
                               deadline - time.monotonic())
                if probe.sim_time() - t0 < end and probe.lowest_z() >= fall:
                    break  # the deadline: the graph stopped advancing
                time.sleep(1.1)  # the counters of this period (/diagnostics at 1 Hz of wall clock)
                with probe.lock:
                    timed = [(t, e) for t, e in probe.efforts[start:] if t - t0 < end]
                    start += len(timed)
                    efforts = [e for _, e in timed]
                    z = [v for t, v in probe.base_z if end - period <= t - t0 < end]
                periods.append({"t_end_s": end, "effort_rms_nm": round(float(np.sqrt(np.mean(np.square(efforts)))), 2)
                                if efforts else None, "commands": len(efforts),
                                "effort_rms_slices_nm": _slice_rms(timed, t0, end - period, SLICE),
                                "base_height_min_m": round(min(z), 3) if z else None,
                                **{f"{node}.{key}": probe.counter(node, key)
                                   for node, keys in LEARNING_COUNTERS.items() for key in keys}})
                if probe.lowest_z() < fall:
                    fell_at = next(t - t0 for t, v in probe.base_z if v < fall)
                    break
        finally:
            rc = launcher.stop()
            log.close()
            probe.close()
    return {"periods": periods, "fell": fell_at is not None,
            "fell_at_s": round(fell_at, 2) if fell_at is not None else None,
            "wall_s": round(time.monotonic() - t_wall, 1), "shutdown_rc": rc}
