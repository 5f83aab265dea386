"""Scaling benchmark (`ciml bench --only scaling`, issue 30 item 1): how the offline stages'
wall time, CPU time and peak memory grow with the number of log samples N.

Data. The headless simulator (recorder.record_bag, as `ciml record --no-ground-truth`) records
`motion` (default trot_35) on `scenario` (default default_gap) at 250 Hz into bags of at most
`bag_samples` samples (default 10,000 = 40 s); bag k has sensor-noise seed k, so every bag is a
fresh recording of the same motion (new sensor and joint-loop noise; the same reference), none
is a copy. A size N is the first N // bag_samples full bags plus one bag of the remaining
N % bag_samples samples (its own seed). Bags are recorded once per run (or kept in `bag_dir` and
reused) and their recording is not timed.

Stages, each the function its `ciml` verb calls, read through the default robot profile as the
CLI does:
- extraction: `ciml extract` = pipeline.load_dataset (bag reading, filtering, eq. 11 extraction)
  and ExtractionResult.save;
- diagnosis: `ciml diagnose --bag ...` = diagnosis.run.diagnose (no --heldout: whole bags, or a
  single bag's last 30 % of time, are held out), writing diagnosis.json and report.html;
- train_lwpr, train_sgpr: `ciml train --learner L --jobs J` = training.train_from_bags (which
  reads and extracts the bags again) and ModelSet.save.

Measurement. Each (stage, N) runs in a fresh process (multiprocessing, spawn): it imports the
stage's modules and loads the robot first (not timed; `rss_before_mb`), then times the call:
wall time (perf_counter), CPU time (user + sys of the process and of any child it reaped:
BLAS threads count, so CPU may exceed wall) and peak RSS (the process's VmHWM, imports
included; `rss_growth_mb` = peak − rss_before). jobs = 1 (default) keeps training in that one
process, so its RSS is the stage's whole memory. Per stage: the least-squares fit of
log y = log a + b log N over the sizes run for wall and CPU time, peak RSS and RSS growth, and
the time per sample. A size whose predicted time (from the sizes already run) exceeds
`stage_limit_s` is skipped and listed under `skipped`; a stage that raises (e.g. the diagnosis
on too few valid samples) is listed under `failed` and the benchmark goes on.
"""
from __future__ import annotations

import math
import os
import shutil
import tempfile
import time
from collections.abc import Sequence

import numpy as np

from ciml_learning.ros.realtime import rss_mb

RATE_HZ = 250.0
STAGES = ("extraction", "diagnosis", "train_lwpr", "train_sgpr")
FIT_KEYS = {"wall_s": "time", "cpu_s": "cpu", "peak_rss_mb": "rss", "rss_growth_mb": "rss_growth"}


# --- the data --------------------------------------------------------------------------------------


def bag_plan(n_samples: int, bag_samples: int) -> list[tuple[int, int]]:
    """(samples, seed) of the bags of a log of n_samples: full bags of bag_samples with seeds
    0, 1, ... (shared by every size) and one bag of the remainder, seed 1_000_000 + remainder."""
    if n_samples < 1 or bag_samples < 1:
        raise ValueError(f"sizes and bag_samples must be positive, got {n_samples} and {bag_samples}")
    full, rest = divmod(int(n_samples), int(bag_samples))
    plan = [(int(bag_samples), k) for k in range(full)]
    if rest:
        plan.append((rest, 1_000_000 + rest))
    return plan


def _record(robot, scenario, motion: str, samples: int, seed: int, bag_dir: str, scenario_name: str) -> str:
    """The bag of `samples` samples with `seed` in bag_dir, recorded unless it is there already."""
    from .recorder import record_bag

    path = os.path.join(bag_dir, f"{motion}_{scenario_name}_n{samples}_seed{seed}")
    if os.path.isdir(path):
        return path
    partial = path + ".partial"
    shutil.rmtree(partial, ignore_errors=True)
    result, _ = record_bag(robot, scenario, motion, samples / RATE_HZ, seed, partial, ground_truth=False,
                           progress=False)
    if result.fell:
        raise RuntimeError(f"{motion} on {scenario_name} fell at t = {result.fall_time:.2f} s (seed {seed}); "
                           "choose a shorter bag_samples or another motion")
    os.rename(partial, path)
    return path


# --- one (stage, N) in its own process ---------------------------------------------------------------


def _cpu_s() -> float:
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def run_stage(stage: str, bags: Sequence[str], out_dir: str, jobs: int = 1) -> dict:
    """Run one stage on `bags` in this process and measure it (called in a fresh process)."""
    t_import = time.perf_counter()
    from ciml_learning.core.profile import load_profile

    profile = load_profile(None)  # `ciml VERB` without --robot
    robot = profile.robot()
    if stage == "extraction":
        from ciml_learning.logs.pipeline import load_dataset
    elif stage == "diagnosis":
        from ciml_learning.diagnosis.run import diagnose
    elif stage.startswith("train_"):
        from ciml_learning.learning.training import (
            train_from_bags,  # (train_sgpr: GPy is imported by its first fit, timed)
        )
    else:
        raise ValueError(f"unknown stage {stage!r}; valid: {', '.join(STAGES)}")
    info: dict = {"import_s": round(time.perf_counter() - t_import, 3), "rss_before_mb": rss_mb(os.getpid())}
    bags = list(bags)
    t0, c0 = time.perf_counter(), _cpu_s()
    if stage == "extraction":
        ds = load_dataset(robot, bags, progress=False, profile=profile)
        t1 = time.perf_counter()
        ds.targets.save(os.path.join(out_dir, "targets.npz"), robot, {"bags": ds.bags})
        info.update(log_samples=int(len(ds.targets.t)), valid_samples=ds.n_valid, load_s=round(t1 - t0, 3),
                    save_s=round(time.perf_counter() - t1, 3))
    elif stage == "diagnosis":
        result = diagnose(robot, bags, None, os.path.join(out_dir, "diagnosis"), progress=False, profile=profile)
        info.update(valid_samples=int(result["data"]["samples"] + result["data"]["heldout_samples"]),
                    effects=[e["type"] for e in result["effects"]])
    else:
        ms = train_from_bags(robot, bags, stage.split("_", 1)[1], n_jobs=jobs, progress=False, profile=profile)
        t1 = time.perf_counter()
        ms.save(os.path.join(out_dir, "model"))
        tr = ms.training_
        info.update(log_samples=int(tr["samples"]), valid_samples=int(tr["valid_samples"]), load_s=tr["load_seconds"],
                    fit_s=tr["fit_seconds"], save_s=round(time.perf_counter() - t1, 3))
    info["wall_s"] = round(time.perf_counter() - t0, 3)
    info["cpu_s"] = round(_cpu_s() - c0, 3)
    info["peak_rss_mb"] = rss_mb(os.getpid(), "VmHWM")
    info["rss_growth_mb"] = round(info["peak_rss_mb"] - info["rss_before_mb"], 1)
    return info


def measure_in_child(stage: str, bags: Sequence[str], jobs: int = 1) -> dict:
    """run_stage in a fresh spawned process (so its peak RSS is that stage's alone)."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    with tempfile.TemporaryDirectory(prefix="ciml_scaling_out_") as out_dir:
        with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
            return pool.submit(run_stage, stage, list(bags), out_dir, jobs).result()


# --- the fits ---------------------------------------------------------------------------------------


def power_fit(n: Sequence[float], y: Sequence[float]) -> dict | None:
    """y ≈ a·N^b by least squares on log-log: {"b", "a"}; None with fewer than two sizes or a y ≤ 0."""
    n_arr, y_arr = np.asarray(n, float), np.asarray(y, float)
    if len(n_arr) < 2 or len(np.unique(n_arr)) < 2 or not np.all(np.isfinite(y_arr)) or np.any(y_arr <= 0):
        return None
    b, log_a = np.polyfit(np.log(n_arr), np.log(y_arr), 1)
    return {"b": round(float(b), 3), "a": float(f"{math.exp(log_a):.4g}")}


def _predicted_s(runs: list[dict], n: int) -> float | None:
    """Wall time of size n extrapolated from the runs so far (fitted exponent; linear from one run)."""
    if not runs:
        return None
    fit = power_fit([r["samples"] for r in runs], [r["wall_s"] for r in runs])
    last = runs[-1]
    b = fit["b"] if fit is not None else 1.0
    return float(last["wall_s"] * (n / last["samples"]) ** max(b, 1.0))


def summarize(runs: list[dict]) -> dict:
    """Per-stage fits over the runs (exponents of time, CPU, peak RSS and its growth) and µs per sample."""
    n = [r["samples"] for r in runs]
    out: dict = {}
    for key, name in FIT_KEYS.items():
        fit = power_fit(n, [r[key] for r in runs])
        out[f"{name}_exponent"] = fit["b"] if fit else None
        out[f"{name}_coefficient"] = fit["a"] if fit else None
    out["us_per_sample"] = {str(r["samples"]): r["us_per_sample"] for r in runs}
    return out


def _ints(text: str | Sequence[int]) -> list[int]:
    if isinstance(text, str):
        return [int(float(s)) for s in text.replace("_", "").split(",") if s.strip()]
    return [int(s) for s in text]


def scaling_benchmark(sizes: str | Sequence[int] = "10000,100000,1000000", stages: str = ",".join(STAGES),
                      motion: str = "trot_35", scenario: str = "default_gap", bag_samples: int = 10_000,
                      jobs: int = 1, stage_limit_s: float = 900.0, bag_dir: str = "") -> dict:
    """Wall time, CPU time and peak RSS of each stage at each size (module docstring)."""
    from ciml_learning.core.robot import load_robot

    from .scenario import resolve_scenario

    size_list = sorted(set(_ints(sizes)))
    stage_list = [s.strip() for s in stages.split(",") if s.strip()]
    unknown = [s for s in stage_list if s not in STAGES]
    if unknown or not stage_list:
        raise ValueError(f"unknown stage(s) {unknown}; valid: {', '.join(STAGES)}")
    bag_samples, jobs, stage_limit_s = int(bag_samples), int(jobs), float(stage_limit_s)
    robot = load_robot()
    scen = resolve_scenario(scenario, robot)
    own_dir = not bag_dir
    bag_root = tempfile.mkdtemp(prefix="ciml_scaling_bags_") if own_dir else bag_dir
    os.makedirs(bag_root, exist_ok=True)
    result: dict = {
        "data": (f"headless simulator (ciml record --no-ground-truth): {motion} on {scenario} at "
                 f"{RATE_HZ:g} Hz, bags of at most {bag_samples} samples ({bag_samples / RATE_HZ:g} s), bag k "
                 "with sensor-noise seed k (fresh noise, same reference), the remainder of a size in one shorter "
                 "bag with its own seed; a size N = the first N // bag_samples bags + that remainder bag"),
        "measurement": ("each (stage, N) in a fresh spawned process; imports and robot loading not timed; "
                        "cpu_s = user + sys of the process (all threads) and its reaped children; peak_rss_mb = "
                        "VmHWM (imports included), rss_growth_mb = peak − RSS before the stage; fits: "
                        "least squares of log y on log N"),
        "stage_functions": {
            "extraction": "ciml_learning.logs.pipeline.load_dataset + ExtractionResult.save (ciml extract)",
            "diagnosis": "ciml_learning.diagnosis.run.diagnose, no --heldout (ciml diagnose)",
            "train_lwpr": "ciml_learning.learning.training.train_from_bags + ModelSet.save (ciml train)",
            "train_sgpr": "ciml_learning.learning.training.train_from_bags + ModelSet.save (ciml train)"},
        "motion": motion, "scenario": scenario, "rate_hz": RATE_HZ, "bag_samples": bag_samples, "jobs": jobs,
        "sizes": size_list, "stages": {s: {"runs": []} for s in stage_list}, "skipped": [], "failed": [],
        "stage_limit_s": stage_limit_s,
    }
    try:
        t0 = time.perf_counter()
        bags: dict[int, list[str]] = {}
        for n in size_list:
            bags[n] = [_record(robot, scen, motion, k, seed, bag_root, scenario)
                       for k, seed in bag_plan(n, bag_samples)]
        result["data_recording_s"] = round(time.perf_counter() - t0, 2)
        for n in size_list:
            for stage in stage_list:
                runs = result["stages"][stage]["runs"]
                predicted = _predicted_s(runs, n)
                if predicted is not None and predicted > stage_limit_s:
                    result["skipped"].append({"stage": stage, "samples": n, "predicted_s": round(predicted, 1),
                                              "reason": f"predicted wall time > stage_limit_s = {stage_limit_s:g} s"})
                    continue
                try:
                    info = measure_in_child(stage, bags[n], jobs)
                except Exception as err:  # e.g. too few valid samples for the diagnosis at a tiny N
                    result["failed"].append({"stage": stage, "samples": n, "error": f"{type(err).__name__}: {err}"})
                    continue
                info["samples"] = n
                info["bags"] = len(bags[n])
                info["us_per_sample"] = round(1e6 * info["wall_s"] / n, 2)
                runs.append(info)
        for stage in stage_list:
            result["stages"][stage].update(summarize(result["stages"][stage]["runs"]))
        return result
    finally:
        if own_dir:
            shutil.rmtree(bag_root, ignore_errors=True)
