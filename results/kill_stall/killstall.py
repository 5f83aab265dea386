"""Research script (results/LIVE_GRAPH.md, twelfth session), run from the repo with the venv:
    [DUMP=0] [DUMP_AFTER=0.25] [KILLS=6 DOWN=1.5 UP=5] [RMW_FASTRTPS_PUBLICATION_MODE=ASYNCHRONOUS] \
        python killstall.py OUT_DIR
(the A/B runs passed a third argument, the launch file's learning_dds_transports of commits
75b802c..5ba5efc, since removed: rmw_fastrtps ignores it under LOCALHOST)
Reproduce the post-SIGKILL stall: default containers, free-running
kill the online learner 3x.
While no /base_state arrives for > 0.25 s of wall, py-spy dump (native) the containers (py-spy 0.4.3 at /tmp/py-spy;
its pauses lengthen the gaps: DUMP=0 for the counts)."""
import json
import os
import subprocess
import sys
import threading
import time

sys.path.insert(0, os.path.join(os.getcwd(), "test"))  # run from the repo
from test_live_graph import DEFAULT, NODES, diagnosing, rate_probe, shipped_file, walks

from ciml_learning.ros.launch_file import load
from ciml_learning.ros.launcher import Launcher

out = sys.argv[1]
os.makedirs(out, exist_ok=True)
DUMP = os.environ.get("DUMP", "1") == "1"
DUMP_AFTER = float(os.environ.get("DUMP_AFTER", "0.25"))  # [s] without /base_state before a dump
probe = rate_probe()
log = open(f"{out}/launch.log", "w")
launcher = Launcher(load(shipped_file(), {"model_dir": f"{out}/model", "containers": DEFAULT, "lockstep": "false"}),
                    out=log, log_dir=out)
launcher.start()
assert probe.wait_for(lambda: probe.first_torque_stamp is not None, 180)
assert probe.wait_for(lambda: all(diagnosing(probe, n) for n in NODES), 180)
walks(probe, 2.0, 60.0)
bridge = next(n for n in launcher.nodes if "mujoco_bridge" in n.label or "control" in n.label)
print("nodes", [(n.label, n.proc.pid) for n in launcher.nodes], flush=True)
pids = {n.label: n.proc.pid for n in launcher.nodes}
stop = False
dumps = []
def watch():
    last_n, last_wall = 0, time.monotonic()
    k = 0
    while not stop:
        time.sleep(0.05)
        with probe.lock:
            n = len(probe.base_z)
        now = time.monotonic()
        if n != last_n:
            if now - last_wall > 0.25:
                with probe.lock:
                    sim_adv = probe.base_z[-1][0] - probe.base_z[last_n - 1][0]
                dumps.append({"gap": round(now - last_wall, 3), "sim": round(sim_adv, 3),
                              "at": round(now - t_start, 1)})
            last_n, last_wall = n, now
        elif DUMP and now - last_wall > DUMP_AFTER and k < 12:
            k += 1
            for label, pid in pids.items():
                if label in ("control", "mujoco_bridge", "learning"):
                    r = subprocess.run(["/tmp/py-spy", "dump", "--native", "--pid", str(pid)],
                                       capture_output=True, text=True)
                    with open(f"{out}/dump_{k}_{label}.txt", "w") as f:
                        f.write(f"stalled {now - last_wall:.2f}s at {now - t_start:.1f}\n" + r.stdout + r.stderr)
t_start = time.monotonic()
th = threading.Thread(target=watch, daemon=True)
th.start()
with probe.lock:
    t0 = probe.base_x[-1][0]
wall0 = time.monotonic()
for i in range(int(os.environ.get("KILLS", "3"))):
    learner = next(n for n in launcher.nodes if n.label == "online_learner")
    learner.stopping = True
    learner.proc.kill()
    learner.proc.wait(timeout=10)
    launcher.nodes.remove(learner)
    print(f"killed at {time.monotonic() - t_start:.1f}", flush=True)
    time.sleep(float(os.environ.get("DOWN", "3")))
    launcher.start(["online_learner"])
    pids["online_learner"] = next(n for n in launcher.nodes if n.label == "online_learner").proc.pid
    print(f"restarted at {time.monotonic() - t_start:.1f}", flush=True)
    time.sleep(float(os.environ.get("UP", "7")))
wall = time.monotonic() - wall0
with probe.lock:
    t1 = probe.base_x[-1][0]
stop = True
print(json.dumps({"pace": (t1 - t0) / wall, "sim": t1 - t0, "wall": wall, "gaps": dumps}), flush=True)
launcher.stop()
probe.close()
