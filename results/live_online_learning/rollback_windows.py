"""Research script (results/LIVE_GRAPH.md, twenty-first session), run from the repo with the venv:
    python results/live_online_learning/rollback_windows.py ROBOT SECONDS
The shipped graph (trot_35, the robot's own scenario, no learning: the nominal model) for SECONDS
of simulated time after the stand; every 0.05 s, the RMS feedback effort of the last 0.25 s (the
rollback's window) against the RMS of the 5 s before it (its baseline): how far a healthy trot's
window rises above 1.5 × the baseline (the sudden-rise rule without its margin)."""
import json
import sys
import tempfile

import numpy as np

from ciml_learning.core.profile import load_profile
from ciml_learning.ros.graph_probe import GraphProbe
from ciml_sim.live_bench import start_graph

robot_name, seconds = sys.argv[1], float(sys.argv[2])
robot = load_profile(robot_name).robot()
with tempfile.TemporaryDirectory() as tmp:
    probe = GraphProbe(effort_robot=robot, nice=10)
    launcher, log = start_graph({"robot": robot_name, "online_learning": "false", "model_dir": tmp + "/m"}, tmp)
    try:
        assert probe.wait_for(lambda: probe.first_torque_stamp is not None, 120)
        t0 = probe.first_torque_stamp * 1e-9
        probe.wait_for(lambda: probe.sim_time() - t0 >= seconds + 5, 40 * seconds)
        with probe.lock:
            te = np.array(probe.efforts)
    finally:
        launcher.stop()
        probe.close()
t, e = te[:, 0] - te[0, 0], te[:, 1]
rows = []
for tc in np.arange(13.0, t[-1], 0.05):  # after the stand, the first steps and a full baseline
    w = e[(t > tc - 0.25) & (t <= tc)]
    b = e[(t > tc - 5.25) & (t <= tc - 0.25)]
    if len(w) > 10 and len(b) > 500:
        rw, rb = np.sqrt(np.mean(w ** 2)), np.sqrt(np.mean(b ** 2))
        rows.append((rw, rb, rw - 1.5 * rb))
r = np.array(rows)
print(json.dumps({"robot": robot_name, "windows": len(r), "effort_rms": float(np.sqrt(np.mean(e[t > 8.0] ** 2))),
                  "window_over_baseline_max": float((r[:, 0] / r[:, 1]).max()),
                  "window_over_baseline_p99": float(np.percentile(r[:, 0] / r[:, 1], 99)),
                  "excess_over_1.5x_max_nm": float(r[:, 2].max()), "excess_p99_nm": float(np.percentile(r[:, 2], 99))}))
