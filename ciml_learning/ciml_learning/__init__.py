"""CIML learning: contact-invariant model learning for legged robots (Grandia, Pardo, Buchli, RA-L 2018)."""
from __future__ import annotations

import os
import signal
import sys
from collections.abc import Iterable


def quiet_interrupt_while_starting(executables: Iterable[str]) -> None:
    """In a node executable's own process, SIGINT or SIGTERM while it still imports (numba,
    Pinocchio, MuJoCo: seconds on a loaded machine) ends it with status 0 and no traceback, as
    once it spins (ros_common.run_nodes then installs the handlers it runs with). A user's Ctrl-C
    right after `ciml launch` otherwise printed a KeyboardInterrupt traceback per starting node.
    Nothing happens in any other program that imports the package (tests, the CLI).

    The process ends with os._exit: nothing is built or written yet, and a SystemExit raised
    from the handler can land in a callback whose exceptions Python ignores (an import lock's
    weakref callback: CI, 2026-11-28, "Exception ignored in _get_module_lock…cb", after which
    the node started and spun on, its stop request lost)."""
    own = os.path.basename(sys.argv[0]) in set(executables)
    if own and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, _exit_now)


def _exit_now(_signum: int, _frame: object) -> None:
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, RuntimeError, ValueError):  # closed pipe, or interrupted mid-write
            pass
    os._exit(0)


quiet_interrupt_while_starting(("state_filter", "error_extractor", "online_learner", "model_server", "state_publisher",
                                "ciml_container"))
