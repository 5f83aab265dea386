"""Background work for nodes: one thread, only the newest submitted item waits.

The model server loads and validates models on it, the online learner writes snapshots on
it; results are collected from the owner's thread (drain), so the owner never shares
mutable state with the worker and the executor thread is never blocked by file IO.
"""
from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ciml_learning.core.errors import CimlError


@dataclass
class WorkResult:
    item: Any
    value: Any = None
    error: str | None = None
    seconds: float = 0.0


class LatestOnlyWorker:
    """Runs fn(item) on one background thread; only the newest submitted item waits.

    submit() replaces a pending (not yet started) item: for model snapshots and model
    updates only the newest matters. Results (WorkResult) are collected by drain() from
    the owner's thread, so the owner never shares mutable state with the worker.
    Exceptions of fn become WorkResult.error (one line); the worker keeps running.
    """

    def __init__(self, fn: Callable[[Any], Any], name: str = "ciml-worker") -> None:
        self.fn = fn
        self._cond = threading.Condition()
        self._pending: list[Any] = []
        self._running = False
        self._closed = False
        self._results: deque[WorkResult] = deque()
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    @property
    def busy(self) -> bool:
        with self._cond:
            return self._running or bool(self._pending)

    def submit(self, item: Any) -> bool:
        """Queue item; returns True if it replaced an item that had not started yet."""
        with self._cond:
            replaced = bool(self._pending)
            self._pending = [item]
            self._cond.notify()
            return replaced

    def drain(self) -> list[WorkResult]:
        out = []
        while self._results:
            out.append(self._results.popleft())
        return out

    def _loop(self) -> None:
        while True:
            with self._cond:
                while not self._pending and not self._closed:
                    self._cond.wait()
                if not self._pending:
                    return
                item = self._pending.pop()
                self._running = True
            t0 = time.perf_counter()
            try:
                result = WorkResult(item, value=self.fn(item))
            except CimlError as err:
                result = WorkResult(item, error=str(err))
            except Exception as err:  # noqa: BLE001 - the worker must survive any failure and report it
                result = WorkResult(item, error=f"{type(err).__name__}: {err}")
            result.seconds = time.perf_counter() - t0
            self._results.append(result)
            with self._cond:
                self._running = False
                self._cond.notify_all()

    def close(self, timeout: float = 30.0) -> None:
        """Finish the pending item (if any) and stop the thread."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        self._thread.join(timeout)


