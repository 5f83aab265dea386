"""Implementations of the learning-side `ciml` verbs (argument namespace in, exit code out)."""
from __future__ import annotations

import argparse
import json
import sys


def play(args: argparse.Namespace) -> int:
    from .replay import play_bag

    counts = play_bag(args.bag, rate=args.rate)
    print(json.dumps({"published": counts}))
    return 0


def bench(args: argparse.Namespace) -> int:
    from .bench import run
    from .fileio import check_out_file

    check_out_file(args.out)
    run(args.only, args.out, dict(args.set))
    return 0


def extract(args: argparse.Namespace) -> int:
    from .cli import profile_from_args, robot_from_args
    from .fileio import check_out_file
    from .pipeline import load_dataset

    check_out_file(args.out)
    robot = robot_from_args(args)
    ds = load_dataset(robot, args.bag, profile=profile_from_args(args))
    inputs = {"rate_hz": ds.rate_hz, "actuation_observed": ds.u_observed, "warnings": ds.warnings,
              "inputs": [{k: i[k] for k in ("bag", "rate_hz", "u_observed", "sources")} for i in ds.inputs]}
    ds.targets.save(args.out, robot, {"bags": ds.bags, "rejected": ds.rejected, **inputs})
    print(json.dumps({"out": args.out, "samples": len(ds.targets.t), "valid": ds.n_valid, "rejected": ds.rejected,
                      "rate_hz": ds.rate_hz, "actuation_observed": ds.u_observed}))
    for w in ds.warnings:
        print(f"ciml extract: warning: {w}", file=sys.stderr)
    return 0
