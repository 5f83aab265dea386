"""`ciml bench`: speed benchmarks, one JSON document.

Each benchmark is a function in the module that owns the algorithm (so it measures
the code the product runs); this file only runs them and records the machine.
Compare numbers from one run only: the machines are shared and noisy.
"""
from __future__ import annotations

import importlib
import json
import os
import platform
import subprocess
import sys
import time

from .fileio import atomic_write_json

BENCHMARKS: dict[str, tuple[str, str, dict]] = {
    # name: (module, function, kwargs)
}


def register(name: str, module: str, function: str, **kwargs) -> None:
    BENCHMARKS[name] = (module, function, kwargs)


register("extraction_throughput", "ciml_learning.extraction", "throughput_benchmark", n_samples=50_000)
register("lwpr_cross_2d", "ciml_learning.training", "lwpr_cross_benchmark", n_samples=20_000)
register("lwpr_online_30dims", "ciml_learning.training", "online_benchmark", n_warmup=20_000, n_samples=2_000)
register("train_lwpr_paper_size", "ciml_learning.training", "train_benchmark", learner="lwpr", n_samples=54_000)
register("train_sgpr_paper_size", "ciml_learning.training", "train_benchmark", learner="sgpr", n_samples=54_000)
register("online_nodes_per_sample", "ciml_learning.online", "online_nodes_benchmark", n_warmup=20_000, n_samples=2_000)
register("id_controller_step", "ciml_control.controller", "compute_benchmark", motion="trot_35", n_steps=2000)
register("id_controller_dds_latency", "ciml_control.benchmarks", "dds_latency_benchmark", duration_s=5.0)
register("sim_headless_speed", "ciml_sim.recorder", "speed_benchmark", motion="trot_35", duration=4.0)
register("sim_bridge_rate", "ciml_sim.benchmarks", "rate_benchmark", seconds=8.0, publish_rate=250.0)
register("diagnosis_50k", "ciml_sim.benchmarks", "diagnosis_benchmark", n_samples=50_000)
register("live_graph_rates", "ciml_learning.live_bench", "graph_rates", duration=60.0)
register("live_online_learning", "ciml_learning.live_bench", "online_learning_effort", duration=60.0)


def _machine() -> dict:
    cpu = ""
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), "")
    except OSError:
        pass
    commit = ""
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                                cwd=os.path.dirname(__file__)).stdout.strip()
    except OSError:
        pass
    return {"cpu": cpu, "cores": os.cpu_count(), "python": sys.version.split()[0],
            "platform": platform.platform(), "commit": commit}


def run(names: list[str] | None, out: str) -> dict:
    from .errors import CimlError

    selected = names or list(BENCHMARKS)
    unknown = [n for n in selected if n not in BENCHMARKS]
    if unknown:
        raise CimlError(f"unknown benchmark(s) {unknown}; available: {sorted(BENCHMARKS)}")
    result = {"machine": _machine(), "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "benchmarks": {}}
    for name in selected:
        module, function, kwargs = BENCHMARKS[name]
        print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        value = getattr(importlib.import_module(module), function)(**kwargs)
        value["wall_time_s"] = round(time.perf_counter() - t0, 3)
        result["benchmarks"][name] = value
        atomic_write_json(out, result)  # partial results survive a later failure
    print(json.dumps(result["benchmarks"], indent=1))
    return result
