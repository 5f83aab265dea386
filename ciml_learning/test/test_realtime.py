"""ciml_learning.ros.realtime: SCHED_FIFO for every thread of a process, or the reason why not.
Run in child processes, so the test runner itself is never real-time scheduled."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest
from rosutil import fifo_permitted

from ciml_learning.ros import realtime

CHILD = """
import os, sys, threading, time
from ciml_learning.ros import realtime
early = threading.Thread(target=time.sleep, args=(2,), daemon=True)
early.start()                                 # exists before: switched
print(realtime.set_fifo_priority(int(sys.argv[1])))
later = threading.Thread(target=time.sleep, args=(2,), daemon=True)
later.start()                                 # started after: inherits
policies = {realtime.scheduling_policy(os.getpid(), int(t)) for t in os.listdir(f"/proc/{os.getpid()}/task")}
print(sorted(policies))
"""


def run_child(priority: int) -> list[str]:
    out = subprocess.run([sys.executable, "-c", CHILD, str(priority)], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return out.stdout.splitlines()


@pytest.mark.skipif(not fifo_permitted(), reason="this user may not use SCHED_FIFO (no rtprio limit)")
def test_every_thread_real_time_scheduled_including_later_ones():
    failed, policies = run_child(20)
    assert failed == "None"
    assert policies == str([os.SCHED_FIFO])


def test_a_refused_priority_is_a_reason_and_nothing_changes():
    failed, policies = run_child(200)  # beyond SCHED_FIFO's 1..99: refused for everyone
    assert "SCHED_FIFO priority 200 refused" in failed
    assert policies == str([os.SCHED_OTHER])


def test_scheduling_policy_of_this_process_is_normal():
    assert realtime.scheduling_policy(os.getpid()) == os.SCHED_OTHER


CHILD_SOME = """
import os, threading, time
from ciml_learning.ros import realtime
before = realtime.thread_ids()
mine = threading.Thread(target=time.sleep, args=(2,), daemon=True)
mine.start()                                  # the only thread to switch
print(realtime.set_fifo_priority(20, realtime.thread_ids() - before))
child = os.fork()                             # forked by the untouched main thread: not real-time
if child == 0:
    os._exit(realtime.scheduling_policy(os.getpid()))
print(realtime.scheduling_policy(os.getpid(), mine.native_id), realtime.scheduling_policy(os.getpid()),
      os.waitpid(child, 0)[1] >> 8)
"""


@pytest.mark.skipif(not fifo_permitted(), reason="this user may not use SCHED_FIFO (no rtprio limit)")
def test_only_the_given_threads_real_time_scheduled_and_children_of_the_others_normal():
    out = subprocess.run([sys.executable, "-c", CHILD_SOME], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    failed, policies = out.stdout.splitlines()
    assert failed == "None"
    assert policies.split() == [str(os.SCHED_FIFO), str(os.SCHED_OTHER), str(os.SCHED_OTHER)]


CHILD_NICE = """
import os, threading, time
from ciml_learning.ros import realtime
before, start = realtime.thread_ids(), os.getpriority(os.PRIO_PROCESS, 0)
mine = threading.Thread(target=time.sleep, args=(2,), daemon=True)
mine.start()
realtime.set_nice(19, realtime.thread_ids() - before)
print(os.getpriority(os.PRIO_PROCESS, mine.native_id), os.getpriority(os.PRIO_PROCESS, 0) == start)
"""


@pytest.mark.skipif(os.getpriority(os.PRIO_PROCESS, 0) >= 19, reason="already at nice 19")
def test_only_the_given_threads_niced():
    out = subprocess.run([sys.executable, "-c", CHILD_NICE], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["19", "True"]  # the main thread keeps its own


@pytest.mark.parametrize("status", [0, 3])
def test_exit_after_ends_a_process_whose_main_thread_holds_the_gil(status):
    """realtime.exit_after: a native timer thread calls _exit(status) while the main thread is
    blocked in a C call that holds the interpreter lock (as rclpy's node destruction did), where a
    Python watchdog thread cannot run; the process ends with that status, not after the call."""
    import subprocess
    import sys

    code = ("import ctypes, sys\nfrom ciml_learning.ros import realtime\n"
            f"assert realtime.exit_after(0.5, {status})\n"
            "ctypes.PyDLL(None).sleep(30)  # holds the GIL\nsys.exit(9)\n")
    proc = subprocess.run([sys.executable, "-c", code], timeout=20, capture_output=True)
    assert proc.returncode == status, proc.stderr[-500:]
