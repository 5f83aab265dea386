"""CPU per thread of each process of the shipped graph (lockstep, its containers), from
/proc/<pid>/task/*/stat over 20 s after 50 s of running: user+system, or user only with UTIME=1.
Run: python thread_cpu.py [launch_arg=value ...]"""
import os
import sys
import tempfile
import time

from ciml_sim import live_bench

args = dict(a.split("=", 1) for a in sys.argv[1:])
tmp = tempfile.mkdtemp()
launcher, out = live_bench.start_graph({"model_dir": tmp + "/m", **args}, tmp)
time.sleep(50)


def ticks(pid: int) -> dict[str, tuple[str, int]]:
    rows = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{tid}/stat", encoding="utf-8") as f:
                text = f.read()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2:].split()
        user, system = int(fields[11]), int(fields[12])
        rows[tid] = (text[text.index("(") + 1:text.rindex(")")], user if os.environ.get("UTIME") else user + system)
    return rows


pids = {n.label: n.proc.pid for n in launcher.nodes}
before = {k: ticks(p) for k, p in pids.items()}
time.sleep(20)
after = {k: ticks(p) for k, p in pids.items()}
hz = os.sysconf("SC_CLK_TCK")
for k in pids:
    rows = sorted(((after[k][t][1] - before[k].get(t, ("", 0))[1]) / 20 / hz, after[k][t][0]) for t in after[k])
    print(k, "cores", round(sum(c for c, _ in rows), 3), [(round(c, 3), n) for c, n in rows[::-1] if c > 0.005])
launcher.stop()
out.close()
