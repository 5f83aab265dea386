"""A node executable interrupted while it still imports (Ctrl-C right after `ciml launch`) ends with
status 0 and no traceback, as it does once it spins (test/test_live_graph.py)."""
from __future__ import annotations

import os
import signal
import subprocess
import time

import pytest

from ciml_learning.launch_file import find_package_prefix


@pytest.mark.parametrize("pkg, executable", [("ciml_learning", "online_learner"), ("ciml_learning", "ciml_container"),
                                             ("ciml_control", "id_controller"), ("ciml_sim", "mujoco_bridge")])
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_node_interrupted_while_importing_exits_0_without_traceback(pkg, executable, sig):
    path = os.path.join(find_package_prefix(pkg), "lib", pkg, executable)
    env = {**os.environ, "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "ROS_DOMAIN_ID": "97"}
    args = ["--node", "ciml_learning", "state_filter"] if executable == "ciml_container" else []
    proc = subprocess.Popen([path, *args, "--ros-args", "-r", "__node:=start_interrupt"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    time.sleep(0.3)  # the interpreter is up, the node's imports are not done
    proc.send_signal(sig)
    out, _ = proc.communicate(timeout=60)
    assert proc.returncode == 0 and "Traceback" not in out, (proc.returncode, out[-2000:])
