"""Benchmarks of ciml_learning (`ciml bench`, registered in setup.py under the `ciml.benchmarks`
entry points). Each runs the code the product runs, with the settings of the benchmark, and
returns one JSON-able dict. Compare numbers from one run only: the machines are shared and noisy.

The measuring code still lives beside the algorithm it measures (extraction.py, training.py,
online.py); these functions fix each benchmark's size.
"""
from __future__ import annotations

from . import extraction, online, training


def extraction_throughput() -> dict:
    return extraction.throughput_benchmark(n_samples=50_000)


def lwpr_cross_2d() -> dict:
    return training.lwpr_cross_benchmark(n_samples=20_000)


def lwpr_online_30dims() -> dict:
    return training.online_benchmark(n_warmup=20_000, n_samples=2_000)


def train_lwpr_paper_size() -> dict:
    return training.train_benchmark(learner="lwpr", n_samples=54_000)


def train_sgpr_paper_size() -> dict:
    return training.train_benchmark(learner="sgpr", n_samples=54_000)


def online_nodes_per_sample() -> dict:
    return online.online_nodes_benchmark(n_warmup=20_000, n_samples=2_000)
