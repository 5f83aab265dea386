"""The distributed engine of `--cluster` (docs/ARCHITECTURE.md §8): independent work on Dask.

`run_all(fn, items, jobs, cluster)` maps a top-level function over independent items (gap-bench
cases) and returns the results in item order: locally with joblib (cluster None), or on a Dask
distributed scheduler (cluster "tcp://HOST:PORT" or "HOST:PORT"), or on a LocalCluster of N worker
processes on 127.0.0.1 (cluster "local:N"). Dask is the scheduler; CIML writes none of its own.

Failures (issue 31, "bad input"): an unreachable scheduler, no worker, or a worker without the project
installed is a ClusterError with one line, raised before any work is sent; a worker lost mid-run makes
Dask run its task again elsewhere (`retries`, and the scheduler's allowed-failures); what still fails
raises PartialResults, which carries every finished result so the caller writes them as a whole file
marked partial — never a silently shorter run.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from ciml_learning.core.errors import CimlError
from ciml_learning.core.version import package_version

if TYPE_CHECKING:
    from ciml_learning.logs.pipeline import BagMap

LOCAL_PREFIX = "local:"
CONNECT_TIMEOUT = 10.0
"""[s] to reach a scheduler before giving up with a one-line error."""
WORKER_TIMEOUT = 60.0
"""[s] to wait for the first worker of a remote scheduler."""
RETRIES = 2
"""Runs of a task again after its worker was lost (Dask's `retries`)."""
LOOPBACK = "127.0.0.1"
"""A LocalCluster listens on loopback only (no port open to the network)."""


class ClusterError(CimlError):
    """The Dask cluster cannot run the work (unreachable, no worker, a worker without the project)."""


class PartialResults(CimlError):
    """Some tasks never finished; `results` holds the finished ones (None where a task did not)."""

    def __init__(self, message: str, results: list[Any]) -> None:
        super().__init__(message)
        self.results = results


def parse_cluster(text: str) -> str:
    """A --cluster value: 'local:N' (N ≥ 1) or a scheduler address ('tcp://host:8786', 'host:8786')."""
    import argparse

    if text.startswith(LOCAL_PREFIX):
        n = text[len(LOCAL_PREFIX):]
        if not n.isdigit() or int(n) < 1:
            raise argparse.ArgumentTypeError(f"expected local:N with N ≥ 1 worker processes, got {text!r}")
        return text
    host, _, port = text.split("://", 1)[-1].rpartition(":")
    if not host or not port.isdigit():
        raise argparse.ArgumentTypeError(f"expected a scheduler address HOST:PORT or tcp://HOST:PORT, or local:N; "
                                         f"got {text!r}")
    return text


def _has_module(module: str) -> str:
    """Run on a worker: the CIML version it has, or why the module does not import."""
    try:
        importlib.import_module(module)
    except Exception as err:  # reported per worker by check_workers
        return f"error: {type(err).__name__}: {err}"
    return package_version()


def check_workers(client: Any, module: str) -> None:
    """ClusterError unless every worker imports `module` and has this CIML version."""
    try:
        client.wait_for_workers(1, timeout=WORKER_TIMEOUT)
    except Exception as err:  # distributed raises TimeoutError (asyncio's or the builtin)
        raise ClusterError(f"--cluster: no Dask worker joined the scheduler within {WORKER_TIMEOUT:g} s "
                           f"(start one with `dask worker ADDRESS`)") from err
    for worker, version in sorted(client.run(_has_module, module).items()):
        if version.startswith("error:"):
            raise ClusterError(f"--cluster: worker {worker} cannot import {module} ({version[7:]}); install the "
                               f"project on every worker (README, 'Running on a Dask cluster')")
        if version != package_version():
            raise ClusterError(f"--cluster: worker {worker} runs CIML {version}, this client {package_version()}; "
                               f"install the same commit on every worker")


@contextmanager
def dask_client(address: str, module: str = "ciml_learning") -> Iterator[Any]:
    """A Dask client of `address` (parse_cluster), closed at the end; a LocalCluster for local:N
    (one thread per worker process: each case runs its own processes and BLAS)."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError as err:
        raise ClusterError("--cluster needs dask and distributed (make install; requirements.txt)") from err
    cluster = None
    try:
        if address.startswith(LOCAL_PREFIX):
            cluster = LocalCluster(n_workers=int(address[len(LOCAL_PREFIX):]), threads_per_worker=1, processes=True,
                                   host=LOOPBACK,
                                   dashboard_address=f"{LOOPBACK}:0")  # its HTTP port: loopback, any free one
            client = Client(cluster)
        else:
            client = Client(address, timeout=CONNECT_TIMEOUT)
    except OSError as err:  # includes the connection's TimeoutError
        if cluster is not None:
            cluster.close()
        raise ClusterError(f"--cluster {address}: no Dask scheduler answers ({type(err).__name__}: "
                           f"{str(err).splitlines()[0] if str(err) else 'no detail'})") from err
    try:
        check_workers(client, module)
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


@contextmanager
def joblib_on(address: str) -> Iterator[None]:
    """joblib's Parallel runs on the Dask cluster `address` inside this block (its backend switch:
    code that calls joblib, like the per-dimension fits of parallel.fit_dimensions, runs unchanged)."""
    from joblib import parallel_backend

    with dask_client(address), parallel_backend("dask"):
        yield


def run_all(fn: Callable[[Any], Any], items: Sequence[Any], jobs: int = 1, cluster: str | None = None,
            module: str = "ciml_learning") -> list[Any]:
    """fn(item) for every item, in item order: joblib with `jobs` processes, or on the Dask cluster
    (`module` must import on every worker: where fn lives). fn must be a module-level function."""
    if cluster is None:
        from joblib import Parallel, delayed

        return list(Parallel(n_jobs=jobs)(delayed(fn)(x) for x in items))
    from dask.distributed import as_completed

    results: list[Any] = [None] * len(items)
    with dask_client(cluster, module) as client:
        futures = client.map(fn, list(items), pure=False, retries=RETRIES)
        where = {f.key: i for i, f in enumerate(futures)}
        done = 0
        try:
            for future, result in as_completed(futures, with_results=True):
                results[where[future.key]] = result
                done += 1
        except (Exception, KeyboardInterrupt) as err:
            for f in futures:
                f.cancel()
            raise PartialResults(f"--cluster: {len(items) - done} of {len(items)} tasks did not finish "
                                 f"({type(err).__name__}: {str(err).splitlines()[0] if str(err) else 'interrupted'})",
                                 results) from err
    return results


def bag_mapper(jobs: int = 1, cluster: str | None = None) -> BagMap | None:
    """How pipeline.load_dataset maps its per-bag reads (map_bags): run_all on `cluster`, or with `jobs`
    local processes (−1: every core); None (one bag after the other, in this process) for jobs 1."""
    if cluster is None and jobs == 1:
        return None
    return lambda fn, items: run_all(fn, items, jobs, cluster)
