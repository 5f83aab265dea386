"""A node executable interrupted while it still imports (Ctrl-C right after `ciml launch`) ends with
status 0 and no traceback, as it does once it spins (test/test_live_graph.py)."""
from __future__ import annotations

import os
import signal
import subprocess
import time

import pytest

from ciml_learning.ros.launch_file import find_package_prefix


@pytest.mark.parametrize("pkg, executable", [("ciml_learning", "online_learner"), ("ciml_learning", "ciml_container"),
                                             ("ciml_control", "id_controller"), ("ciml_sim", "mujoco_bridge")])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
@pytest.mark.parametrize("after", [0.0, 0.3], ids=["at-once", "0.3s-later"])
def test_a_node_interrupted_while_importing_exits_0_without_traceback(pkg, executable, sig, after):
    path = os.path.join(find_package_prefix(pkg), "lib", pkg, executable)
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}  # and the run's own ROS_DOMAIN_ID
    args = ["--node", "ciml_learning", "state_filter"] if executable == "ciml_container" else []
    proc = subprocess.Popen([path, *args, "--ros-args", "-r", "__node:=start_interrupt"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        # the package's start-up handler is in place (SIGTERM caught: Python alone does not catch it)
        # and the node's imports (numba, Pinocchio, MuJoCo: seconds) are not done: on a loaded machine
        # a fixed delay could land before the interpreter has run a line of CIML
        deadline = time.monotonic() + 60.0
        while not caught(proc.pid, signal.SIGTERM) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.005)
        assert caught(proc.pid, signal.SIGTERM), "the start-up handler was never installed"
        time.sleep(after)  # at once: ciml_learning's own import still holds its module lock
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:  # never leave a node running for the next tests
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0 and "Traceback" not in out, (proc.returncode, out[-2000:])


def caught(pid: int, sig: int) -> bool:
    """The process has a handler for `sig` (SigCgt of /proc/<pid>/status)."""
    try:
        with open(f"/proc/{pid}/status") as f:
            mask = next(int(line.split()[1], 16) for line in f if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return bool(mask >> (sig - 1) & 1)
