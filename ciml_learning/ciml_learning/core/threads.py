"""Independent chunks of the offline path on the cores of this process, by threads.

The batch core (batch_dynamics) and numpy's stacked linear algebra release the GIL, so chunks of a
log run in parallel threads without copies or processes; their results come back in order, so what
the caller sums or writes is what one thread gives. BLAS is held to one thread meanwhile (the chunks'
small matrices gain nothing from more, and its threads would compete with the chunks'), and at most
two chunks per thread are in flight, so memory stays bounded by the chunk size.
"""
from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from threadpoolctl import threadpool_limits

T = TypeVar("T")
R = TypeVar("R")


def threads_available() -> int:
    """The cores this process may use, or OMP_NUM_THREADS when set (a Dask worker sets it to 1: its
    processes already share the cores)."""
    cores = len(os.sched_getaffinity(0))
    try:
        return max(1, min(cores, int(os.environ.get("OMP_NUM_THREADS", cores))))
    except ValueError:
        return cores


def in_order(fn: Callable[[T], R], items: Iterable[T], threads: int | None = None) -> Iterator[R]:
    """fn(item) for each item, in item order, computed on `threads` threads (None: threads_available)."""
    items = list(items)
    threads = min(threads or threads_available(), len(items))
    if threads <= 1:
        yield from map(fn, items)
        return
    with threadpool_limits(limits=1, user_api="blas"), ThreadPoolExecutor(threads) as pool:
        pending: deque = deque()
        for item in items:
            pending.append(pool.submit(fn, item))
            if len(pending) >= 2 * threads:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
