"""Real-time scheduling of a node process: the `thread_priority` parameter (docs/LIVE_GRAPH.md, rates).

The control path (bridge, reference generator, controller) asks for SCHED_FIFO, as
ros2_control's controller manager does with its own `thread_priority` parameter: on a machine
whose cores are shared with the learning chain, a normally scheduled control loop gets a fair
share of the CPU, not the share it needs, and loses commands (measured in docs/LIVE_GRAPH.md).
Without the right to (root or an rtprio limit, e.g. `@realtime - rtprio 98` in
/etc/security/limits.conf) the process runs normally scheduled and says so once.
"""
from __future__ import annotations

import os

THREAD_PRIORITY = "thread_priority"
"""Name of the node parameter (0 = normal scheduling)."""


def set_fifo_priority(priority: int, pid: int = 0) -> str | None:
    """SCHED_FIFO at `priority` for every thread of process `pid` (0: this one); threads started
    later inherit it. None on success, else why not (one line); threads already switched keep it."""
    task_dir = f"/proc/{pid or os.getpid()}/task"
    try:
        tids = [int(t) for t in os.listdir(task_dir)]
    except OSError as err:
        return f"cannot list the threads ({err.strerror})"
    for tid in tids:
        try:
            os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        except ProcessLookupError:
            continue  # the thread ended meanwhile
        except OSError as err:
            return f"SCHED_FIFO priority {priority} refused ({err.strerror})"
    return None


def scheduling_policy(pid: int, tid: int | None = None) -> int:
    """The scheduling policy of a thread (os.SCHED_OTHER, os.SCHED_FIFO, ...; /proc/<pid>/task/<tid>/stat)."""
    with open(f"/proc/{pid}/task/{tid or pid}/stat") as f:
        return int(f.read().rsplit(")", 1)[1].split()[38])
