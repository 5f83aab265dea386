"""Training at scale: one independent learner per output dimension of a model set
(18 rigid-body + 12 actuation), fitted in parallel with joblib (ModelSet.fit calls it).

Scaling out (docs/ARCHITECTURE.md §8). fit_dimensions() calls ``joblib.Parallel(n_jobs=...)``
without naming a backend, so it runs on whatever joblib backend is active. Locally that
is loky (processes; each worker's BLAS is limited to one thread). On a cluster, the
same code runs unchanged inside a backend context:

    # Ray (pip install "ray[default]"; workers need ciml_learning installed)
    import joblib, ray
    from ray.util.joblib import register_ray
    ray.init(address="auto")
    register_ray()
    with joblib.parallel_backend("ray"):
        model_set = train_from_bags(robot, bags, "sgpr", n_jobs=-1)

    # Dask (pip install distributed)
    import joblib
    from dask.distributed import Client
    client = Client("tcp://scheduler:8786")
    with joblib.parallel_backend("dask"):
        model_set = train_from_bags(robot, bags, "sgpr", n_jobs=-1)

Each job receives only its dimension's rows (X, y) and returns a fitted learner, so a
job is independent of every other; there is no scheduler of our own. Jobs are
submitted largest first (the base wrench's dimensions have 26-D inputs) for load balance.

Why BLAS threads are pinned to one per job: on this 2-core machine GPy's sparse-GP
gradients ran ~10× slower with OpenBLAS's default threading than with one thread per
process (measured: 100 L-BFGS iterations, 2,000 points, 3-D: 11.3 s vs 1.3 s).
"""
from __future__ import annotations

import time
from collections.abc import Iterable, Sequence

import numpy as np
from threadpoolctl import threadpool_limits

from ciml_learning.learning.learners import Learner, learner_class


def _fit_one(learner: str, params: dict, X: np.ndarray, y: np.ndarray) -> tuple[Learner, float]:
    t0 = time.perf_counter()
    with threadpool_limits(limits=1, user_api="blas"):
        model = learner_class(learner).from_params(params).fit(X, y)
    return model, time.perf_counter() - t0


def fit_dimensions(learner: str, params: Sequence[dict], jobs: Sequence[tuple[int, np.ndarray, np.ndarray]],
                   n_jobs: int = 1, progress: bool = False, names: Sequence[str] | None = None) -> list[Learner]:
    """Fit one learner per job (index, X, y) in parallel; returns the models in job order.

    n_jobs follows joblib (−1: all cores); the active joblib backend is used (module
    docstring: Ray/Dask). Shows a tqdm bar over dimensions with progress=True.
    """
    from joblib import Parallel, delayed
    from tqdm import tqdm

    if not jobs:
        return []
    # largest jobs first (rows × inputs) so the last jobs to finish are short ones
    order = sorted(range(len(jobs)), key=lambda k: -jobs[k][1].shape[0] * jobs[k][1].shape[1])
    tasks = (delayed(_fit_one)(learner, params[k], jobs[k][1], jobs[k][2]) for k in order)
    results: list[Learner | None] = [None] * len(jobs)
    bar = tqdm(total=len(jobs), desc=f"train {learner}", unit="dim", disable=not progress, leave=False)
    with bar:
        stream: Iterable[tuple[int, tuple[Learner, float]]]
        if n_jobs == 1:
            stream = ((k, _fit_one(learner, params[k], jobs[k][1], jobs[k][2])) for k in order)
        else:
            parallel = Parallel(n_jobs=n_jobs, return_as="generator")
            stream = zip(order, parallel(tasks))
        for k, (model, seconds) in stream:
            results[k] = model
            if names is not None:
                bar.set_postfix_str(f"{names[k]} {seconds:.1f}s")
            bar.update(1)
    return results  # type: ignore[return-value]
