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
    Nothing happens in any other program that imports the package (tests, the CLI)."""
    own = os.path.basename(sys.argv[0]) in set(executables)
    if own and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: sys.exit(0))


quiet_interrupt_while_starting(("state_filter", "error_extractor", "online_learner", "model_server", "state_publisher",
                                "ciml_container"))
