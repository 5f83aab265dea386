"""The live graph as a user starts it: the shipped launch file, `ciml launch`, start orders, SIGINT.

Every test runs the shipped `ciml_sim/launch/closed_loop.launch.yaml` through the same
launcher as `ciml launch` (ciml_learning.ros.launcher) on this run's own DDS domain (loopback
only, conftest.py) and watches the graph with ciml_learning.ros.graph_probe.GraphProbe (the
benchmarks' probe). Each wait is bounded; on a loaded machine start-up is slow, so the
bounds are generous and the checks are on simulated time (message stamps).
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from rosutil import fifo_permitted

from ciml_learning.core import topics
from ciml_learning.ros import realtime
from ciml_learning.ros.graph_probe import GraphProbe
from ciml_learning.ros.launch_file import find_package_share, load
from ciml_learning.ros.launcher import Launcher
from ciml_sim.live_bench import NOMINAL_RATES_HZ, PROBE_PRIORITY

pytestmark = [pytest.mark.slow, pytest.mark.ros]

NODES = ("mujoco_bridge", "reference_generator", "id_controller", "model_server", "state_filter",
         "error_extractor", "online_learner", "state_publisher")
STARTUP = 180.0
"""[s] wall-clock bound for a node to come up (imports, numba caches; a shared 2-core machine)."""
DEFAULT = next(a.default for a in load(os.path.join(find_package_share("ciml_sim"), "launch",
                                                    "closed_loop.launch.yaml")).arguments if a.name == "containers")
"""The launch file's own `containers` (control and learning)."""
STANDING_Z = 0.5
"""[m] base height above which HyQ stands (standing pose 0.61 m; on its trunk < 0.3 m)."""


def shipped_file() -> str:
    return os.path.join(find_package_share("ciml_sim"), "launch", "closed_loop.launch.yaml")


def rate_probe() -> GraphProbe:
    """The tests' probe, SCHED_FIFO below every real-time node where permitted (as live_graph_rates'):
    what it counts is the graph's delivery, not its own wait for the CPU beside the graph."""
    return GraphProbe({t: topics.TYPES[t] for t in NOMINAL_RATES_HZ}, priority=PROBE_PRIORITY)


def diagnosing(probe: GraphProbe, node: str) -> bool:
    """The node publishes /diagnostics: it spins (its constructor has finished)."""
    with probe.lock:
        return any(name.lstrip("/").split("/")[-1] == node for name in probe.diagnostics)


def walks(probe: GraphProbe, sim_seconds: float, wall_timeout: float) -> tuple[float, float, float]:
    """Watch `sim_seconds` of simulated time from now: (x advance [m], lowest z [m], simulated s seen)."""
    assert probe.wait_for(lambda: bool(probe.base_z), 60.0), "no /base_state"
    with probe.lock:
        t0, x0 = probe.base_x[-1]
        i0 = len(probe.base_z) - 1
    probe.wait_for(lambda: probe.base_z[-1][0] - t0 >= sim_seconds, wall_timeout)
    with probe.lock:
        zs = [z for _t, z in probe.base_z[i0:]]
        t1, x1 = probe.base_x[-1]
    return x1 - x0, min(zs), t1 - t0


def children(pid: int) -> list[int]:
    """Processes whose parent is `pid`."""
    out = []
    for entry in os.listdir("/proc"):
        try:
            if entry.isdigit() and int(realtime.stat_fields(int(entry))[1]) == pid:
                out.append(int(entry))
        except OSError:
            continue
    return out


def cmdline(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as f:
            return f.read().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def logs_of(tmp_path, launcher: Launcher) -> dict[str, str]:
    out = {}
    for n in launcher.nodes:
        with open(tmp_path / f"{n.label}.log", encoding="utf-8") as f:
            out[n.label] = f.read()
    return out


@pytest.fixture
def graph(tmp_path):
    """(launcher factory, probe); every node still running at the end is stopped."""
    probe = rate_probe()
    launchers: list[Launcher] = []
    log = open(tmp_path / "launch.log", "w", encoding="utf-8")

    def make(**arguments) -> Launcher:
        # each node its own process (containers:=''), so that any order of nodes can be started
        args = {"model_dir": str(tmp_path / "online_model"), "containers": "", **arguments}
        launcher = Launcher(load(shipped_file(), args), out=log, log_dir=str(tmp_path))
        launchers.append(launcher)
        return launcher

    yield make, probe
    for launcher in launchers:
        launcher.stop()
    log.close()
    probe.close()


def test_ciml_launch_brings_up_the_graph_and_sigint_stops_it(tmp_path):
    """`ciml launch ciml_sim closed_loop.launch.yaml`: all eight nodes in the graph (in the
    file's two containers, the model server's and the learner's own processes), sensors,
    commands, filtered states and predictions flowing; the control container real-time
    scheduled where permitted (SCHED_FIFO 50, else it says so), the model server below it (20), the
    learning container normally scheduled; one SIGINT → every process exits 0."""
    probe = rate_probe()
    probe.recording = True
    proc = subprocess.Popen([os.path.join(sys.prefix, "bin", "ciml"), "launch", "ciml_sim", "closed_loop.launch.yaml",
                             f"model_dir:={tmp_path / 'online_model'}"],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert probe.wait_for(lambda: set(NODES) <= probe.node_names(), STARTUP), probe.node_names()
        flowing = (topics.JOINT_STATES, topics.TORQUE_COMMAND, topics.REFERENCE, topics.FILTERED_STATE,
                   topics.MODEL_ERROR_MEASURED, topics.MODEL_ERROR_PREDICTED)
        assert probe.wait_for(lambda: all(len(probe.receipts[t]) > 50 for t in flowing), STARTUP), \
            {t: len(probe.receipts[t]) for t in flowing}
        assert probe.wait_for(lambda: all(diagnosing(probe, n) for n in NODES), 60.0)
        assert probe.first_torque_stamp is not None  # the controller commands torques (not only damping)
        permitted = fifo_permitted()
        # the control container (thread_priority 50), the model server (20), the learning container normally
        for member, priority in (("mujoco_bridge", 50), ("model_server", 20), ("state_filter", 0)):
            group = [pid for pid in children(proc.pid) if member in cmdline(pid)]
            assert len(group) == 1, [cmdline(pid) for pid in children(proc.pid)]
            fifo = permitted and priority > 0
            policy = realtime.scheduling_policy(group[0])
            assert policy == (os.SCHED_FIFO if fifo else os.SCHED_OTHER), (member, policy)
            assert os.sched_getparam(group[0]).sched_priority == (priority if fifo else 0), member
        proc.send_signal(signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
        probe.close()
    assert proc.returncode == 0, out[-3000:]
    assert "all 4 processes exited cleanly" in out  # the file's containers (control, learning), model_server, learner
    if not permitted:
        assert "normal scheduling (thread_priority)" in out
    assert "Traceback" not in out, out[out.index("Traceback") - 500:][:3000]


ORDERS = {
    # name: list of (nodes started together, seconds to wait before the next group)
    "bridge_first": [(("mujoco_bridge",), 8.0), (NODES[1:], 0.0)],
    "controller_first": [(("reference_generator", "id_controller"), 8.0),
                         (NODES[:1] + NODES[3:], 0.0)],
    "learner_late": [(NODES[:6], 15.0), (NODES[6:], 0.0)],
    "model_server_restarted": [(NODES, 0.0)],
    # the launch file's containers (ciml launch's default layout): learning first, control late
    "containers_learning_first": [(("learning", "online_learner"), 15.0), (("control", "model_server"), 0.0)],
}


@pytest.mark.parametrize("order", list(ORDERS))
def test_start_orders_end_standing_then_walking(graph, order):
    """Whatever the start order, the robot stands until the controller commands it, then
    trots (trot_35: 0.35 m/s) without falling; a restarted model_server changes nothing."""
    make, probe = graph
    launcher = make(containers=DEFAULT) if order.startswith("containers") else make()
    for group, pause in ORDERS[order]:
        launcher.start(list(group))
        if "mujoco_bridge" in group or "control" in group:
            assert probe.wait_for(lambda: bool(probe.base_z), STARTUP), "no /base_state from the bridge"
        if pause:
            deadline = time.monotonic() + pause
            while time.monotonic() < deadline:
                base = probe.latest_base()
                if probe.first_torque_stamp is None:  # the bridge holds the standing pose until commanded
                    assert base is None or base[1] > STANDING_Z, \
                        f"{order}: base at {base[1]:.2f} m before the loop runs"
                time.sleep(0.1)
    assert probe.wait_for(lambda: probe.first_torque_stamp is not None, STARTUP), f"{order}: no torque command"
    base = probe.base_at_first_torque  # None: the first command arrived before any /base_state
    if base is None and probe.base_z:
        base = (probe.base_x[0][1], probe.base_z[0][1])
    assert base is not None and base[1] > STANDING_Z, f"{order}: not standing when the controller took over: {base}"
    if order == "model_server_restarted":
        dx, zmin, seen = walks(probe, 3.0, 60.0)
        assert zmin > STANDING_Z - 0.1, f"fell before the restart (z {zmin:.2f} m)"
        server = next(n for n in launcher.nodes if n.label == "model_server")
        server.stopping = True
        server.proc.send_signal(signal.SIGINT)
        assert server.proc.wait(timeout=20) == 0
        launcher.nodes.remove(server)
        launcher.start(["model_server"])
        assert probe.wait_for(lambda: diagnosing(probe, "model_server"), STARTUP)
    dx, zmin, seen = walks(probe, 8.0, 120.0)
    assert seen >= 8.0, f"{order}: only {seen:.1f} s simulated"
    assert zmin > STANDING_Z - 0.1, (f"{order}: the robot fell (lowest base height {zmin:.2f} m); controller: "
                                     f"{next((v for k, v in probe.diagnostics.items() if 'id_controller' in k), {})}")
    shown = {k: v for k, v in probe.diagnostics.items() if any(n in k for n in ("controller", "server", "learner"))}
    assert dx > 0.35 * 8.0 * 0.5, f"{order}: the base advanced only {dx:.2f} m in 8 s of trot_35; {shown}"


def test_a_node_killed_and_restarted_does_not_stall_the_control_loop(graph):
    """The file's containers as a user starts them (lockstep); the online learner is killed with
    SIGKILL and started again, three times, as a user restarts a crashed node. The robot keeps
    trotting, no other process dies, the control loop never stalls 0.5 s (wall clock passing
    without simulated time), and simulated time keeps 0.8 of the wall clock's pace (lockstep's own
    pace here with the learner restarting beside it: 0.87–0.97).
    A process killed while it holds its shared-memory port's lock blocks every writer to that
    port for up to 1 s (Fast DDS; caught with py-spy: the bridge's /clock publication;
    docs/LIVE_GRAPH.md, Transports): the learner reads no topic of the control path (its
    /reference comes with each learning sample, its clock is the wall clock), so no control-path
    node writes to it. What remains: pauses as the restarted learner comes up (its participant
    reuses the dead one's port): 0.18 s of the bridge once in 126 kills of
    results/kill_stall/killstall.py, 0.34 s at this test's probe once in 7 runs
    (results/LIVE_GRAPH.md, twenty-first session).
    Not free-running: on a host where the control container needs ~0.95 of a core (AMD EPYC, 2
    cores) the kernel's real-time cap (sched_rt_runtime_us, 95 %) stalls it ~50 ms a second and
    HyQ falls against the wall clock without any kill (results/LIVE_GRAPH.md, fourteenth session)."""
    make, probe = graph
    launcher = make(containers=DEFAULT)
    launcher.start()
    assert probe.wait_for(lambda: probe.first_torque_stamp is not None, STARTUP), "no torque command"
    assert probe.wait_for(lambda: all(diagnosing(probe, n) for n in NODES), STARTUP)
    walks(probe, 2.0, 60.0)
    with probe.lock:
        t0, x0, i0 = probe.base_x[-1][0], probe.base_x[-1][1], len(probe.base_z)
    wall0 = time.monotonic()
    with probe.lock:
        probe.receipts.clear()
        probe.recording = True
        i_rec = len(probe.base_z)  # the probe's /base_state receipts from here pair with base_z[i_rec:]
    for _ in range(3):
        learner = next(n for n in launcher.nodes if n.label == "online_learner")
        learner.stopping = True
        learner.proc.kill()
        learner.proc.wait(timeout=10)
        launcher.nodes.remove(learner)
        time.sleep(3.0)
        launcher.start(["online_learner"])
        time.sleep(7.0)
    wall = time.monotonic() - wall0
    with probe.lock:
        probe.recording = False
        wall_at = np.array(probe.receipts[topics.BASE_STATE])
        sim_at = np.array([t for t, _z in probe.base_z[i_rec:]])
        t1, x1 = probe.base_x[-1]
        zmin = min(z for _t, z in probe.base_z[i0:])
    n = min(len(wall_at), len(sim_at))
    # the control loop stalled: wall clock passing without simulated time (lockstep); a pause of the
    # delivery to this probe alone passes simulated time with it
    stall = float(np.max(np.diff(wall_at[:n]) - np.diff(sim_at[:n])))
    assert zmin > STANDING_Z - 0.1, f"the robot fell (lowest base height {zmin:.2f} m)"
    assert x1 - x0 > 0.35 * (t1 - t0) * 0.5, f"the base advanced only {x1 - x0:.2f} m"
    assert [n.label for n in launcher.nodes if n.proc.poll() is not None] == [], "a process of the graph died"
    assert stall < 0.5, f"the control loop stalled {stall:.2f} s"
    assert (t1 - t0) / wall > 0.8, f"simulated {t1 - t0:.1f} s in {wall:.1f} s of wall clock"


SIGINT_ROUNDS = int(os.environ.get("CIML_SIGINT_ROUNDS", "20"))


@pytest.mark.parametrize("containers", ["", None], ids=["processes", "containers"])
def test_sigint_20_times_per_node_exits_0_without_traceback(tmp_path, containers):
    """Each round starts every node of the shipped file at once, each in its own process or
    composed in the file's containers, waits until each node spins (publishes /diagnostics),
    sends each process SIGINT and waits ≤ 10 s: rc 0, no traceback."""
    probe = rate_probe()
    failures: list[str] = []
    try:
        for k in range(SIGINT_ROUNDS):
            round_dir = tmp_path / f"round{k}"
            round_dir.mkdir()
            with open(round_dir / "launch.log", "w", encoding="utf-8") as log:
                args = {"model_dir": str(round_dir / "model")}
                if containers is not None:
                    args["containers"] = containers
                launcher = Launcher(load(shipped_file(), args), out=log, log_dir=str(round_dir))
                with probe.lock:
                    probe.diagnostics.clear()
                launcher.start()
                try:
                    up = probe.wait_for(lambda: all(diagnosing(probe, n) for n in NODES), STARTUP)
                    assert up, f"round {k}: nodes not up: {[n for n in NODES if not diagnosing(probe, n)]}"
                    for n in launcher.nodes:
                        n.stopping = True
                        n.proc.send_signal(signal.SIGINT)
                    for n in launcher.nodes:
                        try:
                            n.returncode = n.proc.wait(timeout=10.0)
                        except subprocess.TimeoutExpired:
                            failures.append(f"round {k}: {n.label} still running 10 s after SIGINT")
                finally:
                    launcher.stop()
            for label, text in logs_of(round_dir, launcher).items():
                rc = next(n.returncode for n in launcher.nodes if n.label == label)
                if rc != 0 or "Traceback" in text:
                    failures.append(f"round {k}: {label} rc {rc}: {text[-800:]}")
    finally:
        probe.close()
    assert not failures, "\n".join(failures[:5]) + f"\n({len(failures)} failures in {SIGINT_ROUNDS} rounds)"
