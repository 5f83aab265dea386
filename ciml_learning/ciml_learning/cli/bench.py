"""`ciml bench`: speed benchmarks, one JSON document.

Each package registers its benchmarks in its setup.py (entry point group `ciml.benchmarks`:
name = "package.benchmarks:function", called without arguments, returning a dict), so
`ciml bench` runs those of the packages installed; this file only runs them and records the
machine. Compare numbers from one run only: the machines are shared and noisy.
"""
from __future__ import annotations

import json
import os
import platform
import signal
import sys
import time
from importlib.metadata import EntryPoint, entry_points
from typing import Any

from ciml_learning.core.fileio import atomic_write_json

BENCHMARK_GROUP = "ciml.benchmarks"


def installed_benchmarks() -> dict[str, EntryPoint]:
    """Name → entry point of every installed package's benchmarks, by package name, then by name
    (setuptools writes a group's entry points sorted). Nothing is imported until a benchmark runs."""
    out: dict[str, EntryPoint] = {}
    for ep in sorted(entry_points(group=BENCHMARK_GROUP), key=lambda e: (getattr(e.dist, "name", "") or "", e.name)):
        out.setdefault(ep.name, ep)
    return out


def _machine() -> dict:
    cpu = ""
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), "")
    except OSError:
        pass
    from ciml_learning.core.version import source_commit

    commit = source_commit()
    return {"cpu": cpu, "cores": os.cpu_count(), "python": sys.version.split()[0],
            "platform": platform.platform(), "commit": commit}


def _interrupt(signum, _frame) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def run(names: list[str] | None, out: str, options: dict[str, str] | None = None) -> dict:
    """Run the selected benchmarks (all by default); `options` (NAME -> VALUE, strings) go to each
    selected benchmark whose function takes a parameter of that name."""
    import inspect

    from ciml_learning.core.errors import CimlError

    benchmarks = installed_benchmarks()
    selected = names or list(benchmarks)
    unknown = [n for n in selected if n not in benchmarks]
    if unknown:
        raise CimlError(f"unknown benchmark(s) {unknown}; available: {sorted(benchmarks)}")
    options = options or {}
    functions = {name: benchmarks[name].load() for name in selected} if options else {}
    taken = {name: set(inspect.signature(fn).parameters) for name, fn in functions.items()}
    unused = sorted(set(options) - set().union(*taken.values())) if options else []
    if unused:
        valid = sorted(set().union(*taken.values()))
        raise CimlError(f"option(s) {unused} taken by none of {selected}; valid: {valid or 'none'}")
    result: dict[str, Any] = {"machine": _machine(), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "benchmarks": {}}
    # SIGTERM ends a run like Ctrl-C: the benchmarks' `finally` stops the graphs they started (by
    # default Python dies at once and leaves them running, on the DDS domain of the next run)
    signal.signal(signal.SIGTERM, _interrupt)
    for name in selected:
        print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        value = benchmarks[name].load()(**{k: v for k, v in options.items() if k in taken.get(name, ())})
        value["wall_time_s"] = round(time.perf_counter() - t0, 3)
        result["benchmarks"][name] = value
        atomic_write_json(out, result)  # partial results survive a later failure
    print(json.dumps(result["benchmarks"], indent=1))
    return result
