"""Fifteenth session: why some runs' learner falls behind. The shipped graph (lockstep, HyQ,
default_gap, trot_35, online learning, seed SEED) for DURATION s of wall clock after the first
command; every 10 s: each process's CPU (cores over the interval, from /proc), the online
learner's CPU per thread, and its counters (samples received/lost, samples learned, invalid,
learn_us_mean) from /diagnostics, watched by a SCHED_FIFO 5 probe.
Run: python trace.py SEED [DURATION] > trace_SEED.json"""
import json
import os
import sys
import tempfile
import time

from ciml_learning.core import topics
from ciml_learning.ros.graph_probe import GraphProbe, cpu_seconds
from ciml_sim import live_bench

seed = sys.argv[1]
duration = float(sys.argv[2]) if len(sys.argv) > 2 else 120.0
tmp = tempfile.mkdtemp()
probe = GraphProbe({topics.JOINT_STATES: topics.TYPES[topics.JOINT_STATES]}, priority=live_bench.PROBE_PRIORITY)
launcher, out = live_bench.start_graph({"model_dir": tmp + "/m", "seed": seed}, tmp)
probe.wait_for(lambda: probe.first_torque_time is not None, 200)
pids = {n.label: n.proc.pid for n in launcher.nodes}
KEYS = ("samples_received", "samples_lost", "samples_learned", "invalid_samples", "learn_us_mean",
        "snapshots_accepted")  # before the learning-sample topic (trace_7x.json): states_received, states_lost, ...


def thread_cpu(pid: int) -> dict[str, float]:
    out: dict[str, float] = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/stat", encoding="utf-8") as f:
                text = f.read()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2:].split()
        name = text[text.index("(") + 1:text.rindex(")")]
        out[f"{name}:{tid}"] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return out


rows = []
c0, t0, th0 = {k: cpu_seconds(p) for k, p in pids.items()}, time.monotonic(), thread_cpu(pids["online_learner"])
start = t0
while time.monotonic() - start < duration:
    time.sleep(10)
    c1, t1, th1 = {k: cpu_seconds(p) for k, p in pids.items()}, time.monotonic(), thread_cpu(pids["online_learner"])
    dt = t1 - t0
    rows.append({"t_s": round(t1 - start, 1), "sim_s": round(probe.sim_time(), 1),
                 "cores": {k: round((c1[k] - c0[k]) / dt, 3) for k in pids},
                 "learner_threads": {k: round((v - th0.get(k, 0.0)) / dt, 3) for k, v in th1.items()
                                     if v - th0.get(k, 0.0) > 0.01 * dt},
                 "learner": {k: probe.counter("online_learner", k) for k in KEYS},
                 "filter": {k: probe.counter("state_filter", k) for k in live_bench.LEARNING_COUNTERS["state_filter"]},
                 "load": os.getloadavg()[0]})
    print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    c0, t0, th0 = c1, t1, th1
launcher.stop()
out.close()
probe.close()
print(json.dumps({"seed": seed, "duration_s": duration, "rows": rows}))
