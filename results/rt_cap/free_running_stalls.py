"""The fourteenth session's free-running runs (results/LIVE_GRAPH.md): the shipped graph (or a part,
`only`) against the wall clock for 30 s after a 5 s warm-up, watched by a SCHED_FIFO 5 probe; prints
the lowest base height, each process's CPU, the bridge's and controller's counters, the largest
gaps per topic at the probe (the stalls), and the base height before a fall.
Run: python free_running_stalls.py all|GROUP,GROUP [launch_arg=value ...]
Fifteenth session: PIN=1 pins the control container to CPU 1 and the other processes and the probe
to CPU 0 after start; CFS=NICE sets every real-time thread of the graph to SCHED_OTHER at NICE."""
import json
import os
import sys
import tempfile
import time

import numpy as np

from ciml_learning.core import topics
from ciml_learning.ros.graph_probe import GraphProbe, cpu_seconds
from ciml_sim import live_bench

only = sys.argv[1].split(",") if sys.argv[1] != "all" else None
args = dict(a.split("=", 1) for a in sys.argv[2:])
tmp = tempfile.mkdtemp()
watched = (topics.JOINT_STATES, topics.TORQUE_COMMAND, topics.REFERENCE, topics.MODEL_ERROR_PREDICTED)
probe = GraphProbe({t: topics.TYPES[t] for t in watched}, priority=live_bench.PROBE_PRIORITY)
probe.recording = True
launcher, out = live_bench.start_graph({"model_dir": tmp + "/m", "lockstep": "false", **args}, tmp, only)
probe.wait_for(lambda: probe.first_torque_time is not None, 200)
time.sleep(5)
pids = {n.label: n.proc.pid for n in launcher.nodes}
if os.environ.get("CFS"):
    for k, p in pids.items():
        for tid in os.listdir(f"/proc/{p}/task"):
            if os.sched_getscheduler(int(tid)) != os.SCHED_OTHER:
                os.sched_setscheduler(int(tid), os.SCHED_OTHER, os.sched_param(0))
                os.setpriority(os.PRIO_PROCESS, int(tid), int(os.environ["CFS"]))
    print("cfs", pids)
if os.environ.get("PIN"):
    for k, p in pids.items():
        for tid in os.listdir(f"/proc/{p}/task"):
            os.sched_setaffinity(int(tid), {1} if k == "control" else {0})
    for tid in os.listdir("/proc/self/task"):
        os.sched_setaffinity(int(tid), {0})
    print("pinned", pids)
c0 = {k: cpu_seconds(p) for k, p in pids.items()}
t0 = time.monotonic()
with probe.lock:
    probe.base_z.clear()
time.sleep(30)
wall = time.monotonic() - t0
c1 = {k: cpu_seconds(p) for k, p in pids.items()}
with probe.lock:
    bz = list(probe.base_z)
    receipts = {k: np.asarray(v) for k, v in probe.receipts.items()}
    diagnostics = {k: v for k, v in probe.diagnostics.items()
                   if any(n in k for n in ("id_controller", "model_server", "mujoco_bridge"))}
print(json.dumps({"only": only, "args": args, "lowest_base_m": round(min(v for _, v in bz), 3),
                  "simulated_s": round(bz[-1][0] - bz[0][0], 2),
                  "cpu_cores": {k: round((c1[k] - c0[k]) / wall, 3) for k in pids}}))
for name, values in diagnostics.items():
    print(name, values)
fall = next((i for i, (_t, v) in enumerate(bz) if v < 0.5), None)
if fall is not None:
    before = [round(v, 3) for _, v in bz[max(0, fall - 750):fall:25]]
    print("fell at", round(bz[fall][0], 2), "s; base height before:", before)
for topic, r in receipts.items():
    gaps = np.diff(r)
    worst = sorted(np.argsort(gaps)[-8:])
    print(topic, len(r), "largest gaps [ms]", [round(1e3 * gaps[j], 1) for j in worst],
          "at [s]", [round(r[j] - r[0], 2) for j in worst])
launcher.stop()
out.close()
probe.close()
