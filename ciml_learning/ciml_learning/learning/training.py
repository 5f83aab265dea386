"""`ciml train` and `ciml evaluate` back ends: bags → model set (train_from_bags), and a
model set scored on extracted targets (evaluate, evaluate_on_bags).

The fitting itself is ModelSet.fit, one independent job per output dimension run in
parallel (parallel.fit_dimensions: joblib, and how the same code scales out on Ray or Dask).
"""
from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from ciml_learning.learning.models import ModelSet


# ------------------------------------------------------------------------------ bags → model set
def train_from_bags(robot, bags: Sequence[str], learner: str, n_jobs: int = -1, progress: bool = True,
                    params: dict | None = None, profile=None) -> ModelSet:
    """`ciml train`: read (through the robot profile), filter and extract the bags
    (pipeline.load_dataset; the bags on n_jobs processes), then fit a model set on the valid samples. Provenance goes to
    model_set.training_."""
    from ciml_learning.learning.cluster import bag_mapper
    from ciml_learning.logs.pipeline import load_dataset

    t0 = time.perf_counter()
    ds = load_dataset(robot, bags, progress=progress, profile=profile, map_bags=bag_mapper(n_jobs))
    tg = ds.targets
    ms = ModelSet.for_robot(robot, learner, params)
    t1 = time.perf_counter()
    ms.fit(tg.inputs, tg.generalized_error, tg.generalized_observed, tg.actuation_error, tg.valid, tg.leg_coupling,
           n_jobs=n_jobs, progress=progress, effort_valid=tg.effort_valid)
    ms.training_ = {
        "bags": ds.bags,
        "samples": int(len(tg.t)),
        "valid_samples": ds.n_valid,
        "effort_valid_samples": int(tg.effort_valid.sum()),
        "rejected": ds.rejected,
        "rate_hz": ds.rate_hz,
        "actuation_observed": ds.u_observed,
        "warnings": ds.warnings,
        "samples_per_dimension": {n: int(c) for n, c in zip(ms.output_names, ms.n_samples_)},
        "n_jobs": n_jobs,
        "load_seconds": round(t1 - t0, 3),
        "fit_seconds": round(time.perf_counter() - t1, 3),
    }
    return ms


def evaluate(model_set: ModelSet, inputs: np.ndarray, rbd_error: np.ndarray, rbd_observed: np.ndarray,
             actuation_error: np.ndarray, valid: np.ndarray, leg_coupling: np.ndarray,
             effort_valid: np.ndarray | None = None) -> dict[str, Any]:
    """Prediction RMSE per dimension on observed, valid samples: nominal (zero error) vs
    learned (measured − predicted), as the paper's Fig. 4/5; plus the fraction of samples
    whose residual lies within ±2 predicted std (calibration of the uncertainty).

    Data as for ModelSet.fit (Φ̃ = J'ᵀΦ̃' and its mask, Γ, the leg coupling C). The base
    wrench is compared as measured, in the base entries of Φ̃' (model-free): w' = Φ̃_base −
    Σ_swing C e (measured) against ŵ − Σ_all C ê (predicted; the variance of ŵ only); a leg
    joint's error where its leg swings; Γ where its torques are usable (effort_valid, as fit)."""
    from ciml_learning.core.physical_bounds import N_BASE

    n_valid = int(np.asarray(valid, bool).sum())
    X, rbd_error, rbd_observed, actuation_error, valid, C = model_set._check_data(
        inputs, rbd_error, rbd_observed, actuation_error, valid, leg_coupling, effort_valid)
    pred = model_set.predict(X, return_var=True)
    joints_measured = np.where(rbd_observed[:, N_BASE:], rbd_error[:, N_BASE:], 0.0)
    measured = np.hstack([rbd_error[:, :N_BASE] - np.einsum("nbj,nj->nb", C, joints_measured),
                          rbd_error[:, N_BASE:], actuation_error])
    predicted = np.hstack([pred.rbd[:, :N_BASE] - np.einsum("nbj,nj->nb", C, pred.rbd[:, N_BASE:]),
                           pred.rbd[:, N_BASE:], pred.actuation])
    std = np.sqrt(np.hstack([pred.rbd_var, pred.actuation_var]))
    dims = []
    for i, name in enumerate(model_set.output_names):
        rows = model_set._usable_rows(i, rbd_error, rbd_observed, actuation_error, valid)
        n = int(rows.sum())
        entry: dict[str, Any] = {"name": name, "kind": model_set.dimension_kind(i), "samples": n,
                                 "learned": model_set.models_[i] is not None}
        if n:
            m = measured[rows, i]
            r = m - predicted[rows, i]
            nominal = float(np.sqrt(np.mean(m * m)))
            learned = float(np.sqrt(np.mean(r * r)))
            entry.update(rmse_nominal=nominal, rmse_learned=learned,
                         reduction=(1.0 - learned / nominal) if nominal > 0 else 0.0,
                         within_2std=float(np.mean(np.abs(r) <= 2.0 * std[rows, i])))
        dims.append(entry)

    def group(kind: str | None) -> dict[str, Any]:
        sel = [d for d in dims if d["samples"] and (kind is None or d["kind"] == kind)]
        if not sel:
            return {"dimensions": 0}
        nom = np.array([d["rmse_nominal"] for d in sel])
        lea = np.array([d["rmse_learned"] for d in sel])
        rms_nom, rms_lea = float(np.sqrt(np.mean(nom ** 2))), float(np.sqrt(np.mean(lea ** 2)))
        return {"dimensions": len(sel), "rmse_nominal": rms_nom, "rmse_learned": rms_lea,
                "reduction": (1.0 - rms_lea / rms_nom) if rms_nom > 0 else 0.0,
                "improved_dimensions": int(np.sum(lea < nom))}

    return {"learner": model_set.learner, "samples": int(len(X)), "valid_samples": n_valid,
            "dimensions": dims,
            "summary": {"rbd": group("rbd"), "actuation": group("actuation"), "all": group(None),
                        "note": "RMS over dimensions of per-dimension RMSE; rbd units N/Nm, actuation Nm"}}


def evaluate_on_bags(robot, model_set: ModelSet, bags: Sequence[str], progress: bool = True,
                     profile=None) -> dict[str, Any]:
    """`ciml evaluate`: evaluate() on the extraction of bags (pipeline.load_dataset, through
    the robot profile)."""
    from ciml_learning.logs.pipeline import load_dataset

    ds = load_dataset(robot, bags, progress=progress, profile=profile)
    tg = ds.targets
    metrics = evaluate(model_set, tg.inputs, tg.generalized_error, tg.generalized_observed, tg.actuation_error,
                       tg.valid, tg.leg_coupling, tg.effort_valid)
    metrics["bags"] = ds.bags
    metrics["rejected"] = ds.rejected
    return metrics
