"""Implementations of `ciml train` and `ciml evaluate` (argument namespace in, exit code out)."""
from __future__ import annotations

import argparse
import json
import time

from .errors import CimlError


def train(args: argparse.Namespace) -> int:
    """`ciml train --bag BAG... --learner lwpr|sgpr --out MODEL_DIR [--jobs N | --cluster ADDRESS]`."""
    from contextlib import nullcontext

    from .cli import profile_from_args, robot_from_args
    from .cliargs import cap_jobs
    from .cluster import joblib_on
    from .fileio import check_out_dir
    from .model_files import is_model_dir
    from .training import train_from_bags

    if args.jobs == 0 or args.jobs < -1:
        raise CimlError(f"--jobs must be a positive number of processes or -1 (all cores), got {args.jobs}")
    args.jobs = cap_jobs(args.jobs)
    check_out_dir(args.out, is_model_dir, "model")  # refused before the training, not after
    robot = robot_from_args(args)
    t0 = time.perf_counter()
    # on a cluster, every dimension's fit is a Dask task (n_jobs −1: as many as the cluster takes)
    with joblib_on(args.cluster) if args.cluster else nullcontext():
        model_set = train_from_bags(robot, args.bag, args.learner, n_jobs=-1 if args.cluster else args.jobs,
                                    progress=True, profile=profile_from_args(args))
    meta = model_set.save(args.out)
    learned = [d["name"] for d in meta["dimensions"] if d["learned"]]
    print(json.dumps({"out": args.out, "learner": args.learner, "samples": meta["training"]["samples"],
                      "valid_samples": meta["training"]["valid_samples"], "learned_dimensions": len(learned),
                      "unlearned": [d["name"] for d in meta["dimensions"] if not d["learned"]],
                      "seconds": round(time.perf_counter() - t0, 2)}))
    return 0


def evaluate(args: argparse.Namespace) -> int:
    """`ciml evaluate --model MODEL_DIR --bag BAG... --out metrics.json`."""
    from .cli import profile_from_args, robot_from_args
    from .fileio import atomic_write_json, check_out_file
    from .models import ModelSet
    from .training import evaluate_on_bags

    check_out_file(args.out)
    robot = robot_from_args(args)
    model_set = ModelSet.load(args.model, robot)
    metrics = evaluate_on_bags(robot, model_set, args.bag, progress=True, profile=profile_from_args(args))
    metrics["model"] = args.model
    atomic_write_json(args.out, metrics)
    print(json.dumps({"out": args.out, **{k: v for k, v in metrics["summary"].items() if k != "note"}}))
    return 0
