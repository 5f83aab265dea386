"""`ciml launch`: start the nodes of a YAML launch file as processes (docs/LIVE_GRAPH.md).

The file is read by ciml_learning.ros.launch_file (the same file `ros2 launch` reads on a
full install). Each node runs as `<prefix>/lib/<pkg>/<exec> --ros-args -r __node:=NAME
-p name:=value …`, found through the ament index by name (this package imports no node
code). Like ros2 launch, the launcher:

- forwards SIGINT/SIGTERM to every node as one SIGINT (each node runs in its own
  process group, so a terminal's Ctrl-C reaches a node once, through the launcher), then
  SIGTERM after `stop_timeout` and SIGKILL 5 s later for a node that does not exit;
- prefixes each output line with the node's name (`[mujoco_bridge] …`), optionally
  also writing it to `<log_dir>/<name>.log`;
- reports a node that exits while the others run (`… died with exit code N`) and keeps
  the others running;
- exits 0 when every node exited cleanly (rc 0), 1 otherwise;
- never leaves orphans: each node gets SIGTERM when the launcher dies, even by SIGKILL
  (Linux PR_SET_PDEATHSIG, kept across the node's exec; nodes started from the main thread),
  so a killed `ciml launch` does not leave a simulator and a controller running on the domain.
Every node inherits ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST unless the caller set it.
"""
from __future__ import annotations

import ctypes
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TextIO

from ciml_learning.ros.launch_file import (
    LaunchDescription,
    LaunchFileError,
    ProcessAction,
    find_executable,
    process_plan,
)

KILL_GRACE = 5.0
"""[s] between SIGTERM and SIGKILL of a node that ignores SIGINT."""
_LIBC = ctypes.CDLL(None, use_errno=True)  # resolved here: the forked child only calls it
PR_SET_PDEATHSIG = 1  # <linux/prctl.h>


def _die_with_launcher(launcher_pid: int) -> Callable[[], None]:
    """preexec_fn of a node: SIGTERM when the launcher's thread that started it ends."""
    def preexec() -> None:
        _LIBC.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)
        if os.getppid() != launcher_pid:  # the launcher died before prctl took effect
            os._exit(1)
    return preexec


@dataclass
class NodeProcess:
    """A started process: one node, or a container of nodes (ProcessAction.composed)."""

    action: ProcessAction
    command: list[str]
    proc: subprocess.Popen
    reader: threading.Thread
    returncode: int | None = None
    stopping: bool = False
    started: float = field(default_factory=time.monotonic)
    lines: list[str] = field(default_factory=list)

    @property
    def label(self) -> str:
        return self.action.label


def node_environment(base: dict[str, str] | None = None) -> dict[str, str]:
    """Environment of every node: loopback-only DDS unless set, unbuffered Python output,
    the venv as ament prefix when no setup script was sourced."""
    env = dict(os.environ if base is None else base)
    env.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    env.setdefault("AMENT_PREFIX_PATH", sys.prefix)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def command(process: ProcessAction) -> list[str]:
    """The command line of one process (executables resolved; LaunchFileError if one is missing):
    `<exec> <node args>`, or `ciml_container --node PKG EXEC <node args> ...` for a container."""
    if not process.composed:
        node = process.nodes[0]
        return [*node.launch_prefix, find_executable(node.pkg, node.executable), *node.ros_arguments()]
    cmd = [*process.nodes[0].launch_prefix, find_executable("ciml_learning", "ciml_container")]
    for node in process.nodes:
        find_executable(node.pkg, node.executable)  # installed as a node of its package
        cmd += ["--node", node.pkg, node.executable, *node.ros_arguments()]
    return cmd


class Launcher:
    """Start, watch and stop the nodes of one launch description."""

    def __init__(self, desc: LaunchDescription, out: TextIO | None = None, log_dir: str | None = None,
                 stop_timeout: float = 10.0, keep_lines: int = 0, env: dict[str, str] | None = None) -> None:
        if not desc.nodes:
            raise LaunchFileError(f"{desc.path}: no node to start")
        names = [n.label for n in desc.nodes]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise LaunchFileError(f"{desc.path}: node name(s) used twice: {', '.join(dup)}")
        self.desc = desc
        self.plan = process_plan(desc)
        labels = [p.label for p in self.plan]
        dup = sorted({n for n in labels if labels.count(n) > 1})
        if dup:
            raise LaunchFileError(f"{desc.path}: process name(s) used twice (a container named like a node?): "
                                  f"{', '.join(dup)}")
        self.cmds = [command(p) for p in self.plan]  # every executable found before anything starts
        self.out = out if out is not None else sys.stdout
        self.log_dir = log_dir
        self.stop_timeout = stop_timeout
        self.keep_lines = keep_lines
        self.env = {**node_environment(env), **desc.environment}  # the file's set_env, as launch applies it
        self.nodes: list[NodeProcess] = []
        self._lock = threading.Lock()
        self._stop_requested = threading.Event()
        self._stop_started: float | None = None
        self._termed = False

    # --- output ------------------------------------------------------------------------
    def _say(self, text: str) -> None:
        with self._lock:
            try:
                self.out.write(text if text.endswith("\n") else text + "\n")
                self.out.flush()
            except (OSError, ValueError):
                pass  # our own stdout closed: keep managing the nodes

    def _read(self, node: NodeProcess) -> None:
        log = open(os.path.join(self.log_dir, f"{node.label}.log"), "w", encoding="utf-8") if self.log_dir else None
        try:
            for line in node.proc.stdout:  # type: ignore[union-attr]
                self._say(f"[{node.label}] {line}")
                if log is not None:
                    log.write(line)
                    log.flush()
                if self.keep_lines:
                    node.lines.append(line)
                    del node.lines[:-self.keep_lines]
        finally:
            if log is not None:
                log.close()

    # --- life cycle ----------------------------------------------------------------------
    def start(self, only: list[str] | None = None) -> list[NodeProcess]:
        """Start every process of the file (or those named in `only`: a container's name or a
        lone node's), containers first, then lone nodes in the file's order. Nodes started from
        the main thread end with the launcher; PR_SET_PDEATHSIG is per thread, so nodes started
        from another thread (which may end before them) are not tied to it."""
        if self.log_dir:
            os.makedirs(self.log_dir, exist_ok=True)
        main = threading.current_thread() is threading.main_thread()
        started = []
        for action, cmd in zip(self.plan, self.cmds):
            if only is not None and action.label not in only:
                continue
            proc = subprocess.Popen(cmd, env={**self.env, **action.environment}, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, text=True, bufsize=1,
                                    process_group=0, preexec_fn=_die_with_launcher(os.getpid()) if main else None)
            node = NodeProcess(action, cmd, proc, threading.Thread(target=lambda: None))
            node.reader = threading.Thread(target=self._read, args=(node,), name=f"out-{action.label}", daemon=True)
            node.reader.start()
            self.nodes.append(node)
            started.append(node)
            self._say(f"[launch] started {action.label} (pid {proc.pid}): {' '.join(cmd)}")
        return started

    def request_stop(self, *_args) -> None:
        """Signal handler: stop every node (SIGINT, then SIGTERM, then SIGKILL)."""
        self._stop_requested.set()

    def poll(self) -> bool:
        """Reap exited nodes, escalate a pending stop; True while a node runs."""
        now = time.monotonic()
        if self._stop_requested.is_set() and self._stop_started is None:
            self._stop_started = now
            for n in self.nodes:
                if n.returncode is None:
                    n.stopping = True
                    self._signal(n, signal.SIGINT)
        if self._stop_started is not None:
            if not self._termed and now - self._stop_started > self.stop_timeout:
                self._termed = True
                for n in self.nodes:
                    if n.proc.poll() is None:
                        self._say(f"[launch] {n.label} still running {self.stop_timeout:g} s after SIGINT: SIGTERM")
                        self._signal(n, signal.SIGTERM)
            if now - self._stop_started > self.stop_timeout + KILL_GRACE:
                for n in self.nodes:
                    if n.proc.poll() is None:
                        self._say(f"[launch] {n.label} ignored SIGTERM: SIGKILL")
                        self._signal(n, signal.SIGKILL)
        running = False
        for n in self.nodes:
            if n.returncode is not None:
                continue
            rc = n.proc.poll()
            if rc is None:
                running = True
                continue
            n.reader.join(timeout=2.0)
            n.returncode = rc
            if n.stopping and rc == 0:
                self._say(f"[launch] {n.label} (pid {n.proc.pid}) exited cleanly")
            elif n.stopping:
                self._say(f"[launch] {n.label} (pid {n.proc.pid}) exited with code {rc} on shutdown")
            else:
                self._say(f"[launch] {n.label} (pid {n.proc.pid}) died with exit code {rc}; "
                          "the other nodes keep running")
        return running

    def _signal(self, node: NodeProcess, sig: int) -> None:
        try:
            node.proc.send_signal(sig)
        except ProcessLookupError:
            pass

    def wait(self, period: float = 0.1) -> int:
        """Until every node has exited: 0 if all exited with rc 0, else 1."""
        while self.poll():
            time.sleep(period)
        failed = [f"{n.label} ({n.returncode})" for n in self.nodes if n.returncode != 0]
        if failed:
            self._say(f"[launch] nodes that did not exit cleanly: {', '.join(failed)}")
            return 1
        self._say(f"[launch] all {len(self.nodes)} processes exited cleanly")
        return 0

    def stop(self, timeout: float | None = None) -> int:
        """Stop every node and wait (for programs that drive a launch, e.g. tests and benchmarks)."""
        self.request_stop()
        return self.wait()

    def pid(self, label: str) -> int:
        return next(n.proc.pid for n in self.nodes if n.label == label)


def launch(desc: LaunchDescription, log_dir: str | None = None, stop_timeout: float = 10.0) -> int:
    """Run the launch description until SIGINT/SIGTERM or until every node has exited."""
    launcher = Launcher(desc, log_dir=log_dir, stop_timeout=stop_timeout)
    previous = {s: signal.signal(s, launcher.request_stop) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        launcher.start()
        return launcher.wait()
    finally:
        if any(n.returncode is None for n in launcher.nodes):  # an unexpected error: never orphan nodes
            launcher.request_stop()
            launcher.wait()
        for s, handler in previous.items():
            signal.signal(s, handler)


def resolve_launch_path(target: str, second: str | None) -> str:
    """`FILE` or `PKG FILE` (as `ros2 launch` takes them: the file under share/PKG/launch)."""
    if second is None:
        return target
    from ciml_learning.ros.launch_file import find_package_share

    return os.path.join(find_package_share(target), "launch", second)
