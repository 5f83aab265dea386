"""The go1 live graph (go1_gap, trot_35, lockstep, seed 42) traced from outside: every command's
feedback effort, the `source` of every prediction, the controller's lag counters every 10 s.

    python live_trace.py learn OUT DURATION            # online learning; every snapshot copied to OUT/keep
    python live_trace.py serve OUT DURATION MODEL ...  # no learning: MODEL from the start, each next one
                                                       # announced (/model_update) 15 s after the one before
    → OUT/<mode>_trace.npz (eff: (stamp [s], effort [Nm]); src_t, src: prediction stamps and sources)
"""
import json
import os
import shutil
import sys
import tempfile
import threading
import time

import numpy as np
import rclpy
from ciml_msgs.msg import ModelError, ModelUpdate
from rclpy.executors import SingleThreadedExecutor

from ciml_learning.core import topics
from ciml_learning.core.profile import load_profile
from ciml_learning.ros.graph_probe import GraphProbe
from ciml_learning.ros.ros_common import COMMAND_QOS
from ciml_sim.live_bench import start_graph

os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
os.environ.setdefault("ROS_DOMAIN_ID", "77")
mode, out, duration, models = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4:]
COUNTERS = ("reference_lag_mean_ms", "reference_lag_p99_ms", "prediction_lag_mean_ms", "prediction_behind_reference",
            "rollbacks", "models_judged", "epsilon_gated")
ctx = rclpy.Context()
rclpy.init(args=[], context=ctx)
node = rclpy.create_node("live_trace", context=ctx)
sources: list = []
node.create_subscription(ModelError, topics.MODEL_ERROR_PREDICTED,
                         lambda m: sources.append((m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec, m.source)),
                         COMMAND_QOS)
announce = node.create_publisher(ModelUpdate, topics.MODEL_UPDATE, COMMAND_QOS)
executor = SingleThreadedExecutor(context=ctx)
executor.add_node(node)
threading.Thread(target=executor.spin, daemon=True).start()
log_dir = tempfile.mkdtemp(prefix="live_trace_")
args = {"robot": "go1", "scenario": "go1_gap", "seed": "42"}
if mode == "learn":
    args["model_dir"] = f"{out}/snaps"
    os.makedirs(f"{out}/keep", exist_ok=True)
else:
    args.update(online_learning="false", model=models[0], model_dir=f"{log_dir}/m")
probe = GraphProbe(effort_robot=load_profile("go1").robot(), nice=10)
launcher, log = start_graph(args, log_dir)
try:
    assert probe.wait_for(lambda: probe.first_torque_stamp is not None, 120)
    t0 = probe.first_torque_stamp * 1e-9
    next_at, i, printed = 15.0, 1, -10.0
    while probe.sim_time() - t0 < duration:
        time.sleep(0.5)
        elapsed = probe.sim_time() - t0
        if elapsed - printed >= 10:
            printed = elapsed
            print(f"{elapsed:.0f} s", {k: probe.counter("id_controller", k) for k in COUNTERS}, flush=True)
        if mode == "learn" and os.path.isdir(f"{out}/snaps"):
            for d in os.listdir(f"{out}/snaps"):
                if d.startswith("snapshot-") and not os.path.exists(f"{out}/keep/{d}"):
                    shutil.copytree(f"{out}/snaps/{d}", f"{out}/keep/{d}")
        elif mode == "serve" and elapsed >= next_at and i < len(models):
            with open(f"{models[i]}/model.json") as f:
                checksum = json.load(f)["checksum"]
            announce.publish(ModelUpdate(model_dir=models[i], learner="lwpr", checksum=checksum))
            i, next_at = i + 1, next_at + 15.0
finally:
    rc = launcher.stop()
    log.close()
    with probe.lock:
        eff = np.array(probe.efforts)
    print("rc", rc, "lowest base", round(probe.lowest_z(), 3), "log", log_dir)
    probe.close()
    executor.shutdown()
    np.savez(f"{out}/{mode}_trace.npz", eff=eff, src_t=np.array([s[0] for s in sources]),
             src=np.array([s[1] for s in sources]))
