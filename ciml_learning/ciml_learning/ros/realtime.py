"""Real-time scheduling of a node process: the `thread_priority` parameter (docs/LIVE_GRAPH.md, rates).

The control path (bridge, reference generator, controller) asks for SCHED_FIFO, as
ros2_control's controller manager does with its own `thread_priority` parameter: on a machine
whose cores are shared with the learning chain, a normally scheduled control loop gets a fair
share of the CPU, not the share it needs, and loses commands (measured in results/LIVE_GRAPH.md).
Without the right to (root or an rtprio limit, e.g. `@realtime - rtprio 98` in
/etc/security/limits.conf) the process runs normally scheduled and says so once.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import os

THREAD_PRIORITY = "thread_priority"
"""Name of the node parameter (0 = normal scheduling)."""


def thread_ids() -> set[int]:
    """The ids of this process's threads now (OSError if /proc cannot be read)."""
    return {int(t) for t in os.listdir(f"/proc/{os.getpid()}/task")}


def set_fifo_priority(priority: int, tids: set[int] | None = None) -> str | None:
    """SCHED_FIFO at `priority` for every thread of this process (or only those of `tids`);
    threads they start later inherit it. None on success, else why not (one line); threads
    already switched keep it."""
    try:
        tids = thread_ids() if tids is None else tids
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


def set_nice(nice: int, tids: set[int]) -> None:
    """Nice level `nice` for the threads `tids` of this process (Linux: a thread's nice is its own;
    threads they start later inherit it); threads that ended meanwhile are skipped."""
    for tid in tids:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        except ProcessLookupError:
            continue


def normal_scheduling() -> None:
    """The calling thread back to normal scheduling (SCHED_OTHER), e.g. a worker that does long,
    non-real-time work inside a real-time process; nothing if it cannot."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))  # pid 0: this thread (Linux)
    except OSError:
        pass


def stat_fields(pid: int, tid: int | None = None) -> list[str]:
    """/proc/<pid>/task/<tid>/stat (the process's own without tid) after the command name, which
    may hold spaces: [0] is proc(5)'s field 3 (state), [1] the parent pid, [11]/[12] utime/stime,
    [38] the policy. OSError once the process has exited."""
    path = f"/proc/{pid}/stat" if tid is None else f"/proc/{pid}/task/{tid}/stat"
    with open(path) as f:
        return f.read().rsplit(")", 1)[1].split()


def rss_mb(pid: int, field: str = "VmRSS") -> float | None:
    """Resident memory of a process [MB] (VmRSS; or VmHWM, its peak), None once it has exited."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return round(int(line.split()[1]) / 1024.0, 1)
    except OSError:
        return None
    return None


def scheduling_policy(pid: int, tid: int | None = None) -> int:
    """The scheduling policy of a thread (os.SCHED_OTHER, os.SCHED_FIFO, ...)."""
    return int(stat_fields(pid, tid)[38])


class _SigevThread(ctypes.Structure):
    _fields_ = [("function", ctypes.c_void_p), ("attribute", ctypes.c_void_p)]


class _SigevUnion(ctypes.Union):
    _fields_ = [("pad", ctypes.c_int * 12), ("thread", _SigevThread)]


class _SigEvent(ctypes.Structure):  # struct sigevent (Linux, glibc)
    _fields_ = [("value", ctypes.c_void_p), ("signo", ctypes.c_int), ("notify", ctypes.c_int),
                ("un", _SigevUnion)]


class _Timespec(ctypes.Structure):
    _fields_ = [("sec", ctypes.c_long), ("nsec", ctypes.c_long)]


class _ITimerspec(ctypes.Structure):
    _fields_ = [("interval", _Timespec), ("value", _Timespec)]


_SIGEV_THREAD, _CLOCK_MONOTONIC = 2, 1
_exit_timers: list = []  # the timers and their events live as long as the process


def exit_after(seconds: float, status: int = 0) -> bool:
    """_exit(status) from a native timer thread in `seconds`, without Python's GIL: a shutdown that
    blocks in a C call holding the GIL (rclpy's node destruction did, for > 5 s) cannot run a
    Python watchdog thread. POSIX timer_create with SIGEV_THREAD calls libc's _exit with the
    timer's value. False where that is not available (then the caller keeps its own fallback)."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True)
        event = _SigEvent(value=status, notify=_SIGEV_THREAD)
        event.un.thread.function = ctypes.cast(libc._exit, ctypes.c_void_p).value
        timer = ctypes.c_void_p()
        if libc.timer_create(_CLOCK_MONOTONIC, ctypes.byref(event), ctypes.byref(timer)) != 0:
            return False
        spec = _ITimerspec(value=_Timespec(int(seconds), int((seconds % 1.0) * 1e9)))
        if libc.timer_settime(timer, 0, ctypes.byref(spec), None) != 0:
            return False
    except (OSError, AttributeError, TypeError):
        return False
    _exit_timers.append((event, timer))
    return True
