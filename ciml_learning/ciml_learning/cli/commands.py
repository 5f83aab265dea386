"""The `ciml` verbs of ciml_learning, implemented (argument namespace in, exit code out); their
options are in cli/verbs.py. Each verb imports what it needs when it runs, so one verb does not
load another's libraries."""
from __future__ import annotations

import argparse
import json
import os
import shlex
import sys
import time

from ciml_learning.cli.main import profile_from_args, robot_from_args
from ciml_learning.core.errors import CimlError


def play(args: argparse.Namespace) -> int:
    from ciml_learning.ros.replay import play_bag

    counts = play_bag(args.bag, rate=args.rate)
    print(json.dumps({"published": counts}))
    return 0


def bench(args: argparse.Namespace) -> int:
    from ciml_learning.cli.bench import run
    from ciml_learning.core.fileio import check_out_file

    check_out_file(args.out)
    run(args.only, args.out, dict(args.set))
    return 0


def extract(args: argparse.Namespace) -> int:
    from ciml_learning.core.fileio import check_out_file
    from ciml_learning.logs.pipeline import load_dataset

    check_out_file(args.out)
    robot = robot_from_args(args)
    ds = load_dataset(robot, args.bag, profile=profile_from_args(args))
    inputs = {"rate_hz": ds.rate_hz, "actuation_observed": ds.u_observed, "warnings": ds.warnings,
              "inputs": [{k: i[k] for k in ("bag", "rate_hz", "u_observed", "sources")} for i in ds.inputs]}
    ds.targets.save(args.out, robot, {"bags": ds.bags, "rejected": ds.rejected, **inputs})
    rates = sorted({float(i["rate_hz"]) for i in ds.inputs})
    print(json.dumps({"out": args.out, "samples": len(ds.targets.t), "valid": ds.n_valid, "rejected": ds.rejected,
                      # the bags' common rate, or each distinct one when they differ
                      "rate_hz": rates[0] if len(rates) == 1 else rates, "actuation_observed": ds.u_observed}))
    for w in ds.warnings:
        print(f"ciml extract: warning: {w}", file=sys.stderr)
    return 0


def _jobs(args: argparse.Namespace) -> int:
    """--jobs checked and capped at the cores available (cli.args.cap_jobs)."""
    from ciml_learning.cli.args import cap_jobs

    if args.jobs == 0 or args.jobs < -1:
        raise CimlError(f"--jobs must be a positive number of processes or -1 (all cores), got {args.jobs}")
    return cap_jobs(args.jobs)


def train(args: argparse.Namespace) -> int:
    """`ciml train --bag BAG... --learner lwpr|sgpr --out MODEL_DIR [--jobs N | --cluster ADDRESS]`."""
    from contextlib import nullcontext

    from ciml_learning.core.fileio import check_out_dir
    from ciml_learning.learning.cluster import joblib_on
    from ciml_learning.learning.model_files import is_model_dir
    from ciml_learning.learning.training import train_from_bags

    args.jobs = _jobs(args)
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
    from ciml_learning.core.fileio import atomic_write_json, check_out_file
    from ciml_learning.learning.models import ModelSet
    from ciml_learning.learning.training import evaluate_on_bags

    check_out_file(args.out)
    robot = robot_from_args(args)
    model_set = ModelSet.load(args.model, robot)
    metrics = evaluate_on_bags(robot, model_set, args.bag, progress=True, profile=profile_from_args(args))
    metrics["model"] = args.model
    atomic_write_json(args.out, metrics)
    print(json.dumps({"out": args.out, **{k: v for k, v in metrics["summary"].items() if k != "note"}}))
    return 0


def diagnose(args: argparse.Namespace) -> int:
    from ciml_learning.diagnosis.report import answers
    from ciml_learning.diagnosis.run import diagnose as run

    robot = robot_from_args(args)
    result = run(robot, args.bag, args.heldout, args.out, progress=True, profile=profile_from_args(args),
                 reference=getattr(args, "reference", None), jobs=_jobs(args), cluster=args.cluster)
    print(f"diagnosis: {os.path.join(args.out, 'diagnosis.json')}")
    print(f"report:    {os.path.join(args.out, 'report.html')}")
    for line in answers(result):
        print(line)
    for w in result["data"].get("warnings", []):
        print(f"warning: {w}")
    if getattr(args, "publish", None) is not None:  # after diagnosis.json is written
        from ciml_learning.ros.gap_publisher import publish_gap_diagnosis

        print(f"publishing on /gap_diagnosis for {args.publish:g} s (Ctrl-C ends the wait)", flush=True)
        matched = publish_gap_diagnosis(result, linger=args.publish)
        print(f"published on /gap_diagnosis ({matched} subscriber(s) matched)")
    return 0


def robot_arguments(args, declared: set[str], given: dict[str, str], path: str) -> dict[str, str]:
    """--robot / --urdf / --feet as the launch arguments robot:= / urdf:= / feet:= (a shipped
    robot's name stays a name, a file becomes absolute); LaunchFileError when the file declares no
    such argument (its nodes could not take the robot) or it is given both ways."""
    from ciml_learning.core.profile import is_robot_name
    from ciml_learning.ros.launch_file import LaunchFileError

    out: dict[str, str] = {}
    if getattr(args, "robot", None) is not None:
        out["robot"] = args.robot if is_robot_name(args.robot) else os.path.abspath(args.robot)
    if getattr(args, "urdf", None) is not None:
        out["urdf"] = profile_from_args(args).urdf  # resolved (erd:) and absolute
    if getattr(args, "feet", None) is not None:
        out["feet"] = ",".join(args.feet)
    for name in out:
        if name not in declared:
            raise LaunchFileError(f"--{name}: {path} declares no launch argument {name!r}, so its nodes cannot "
                                  f"take it (declared: {', '.join(sorted(declared)) or 'none'})")
        if name in given:
            raise LaunchFileError(f"--{name} and {name}:= both given; give the {name} once")
    return out


def launch_command(args) -> int:
    """The `ciml launch` verb."""
    from ciml_learning.ros.launch_file import LaunchFileError, describe, load, parse_arguments
    from ciml_learning.ros.launcher import command, launch, process_plan, resolve_launch_path

    rest = list(args.arguments)
    second = rest.pop(0) if rest and ":=" not in rest[0] and not os.path.isfile(args.file) else None
    path = resolve_launch_path(args.file, second)
    if not os.path.isfile(path):
        raise LaunchFileError(f"launch file {path} not found")
    arguments = parse_arguments(rest)
    desc = load(path, arguments)
    robot = robot_arguments(args, {a.name for a in desc.arguments}, arguments, path)
    if robot:
        desc = load(path, {**arguments, **robot})
    if args.show_args:
        print(describe(desc))
        return 0
    if args.print:
        for process in process_plan(desc):
            env = [f"{k}={shlex.quote(v)}" for k, v in {**desc.environment, **process.environment}.items()]
            print(" ".join(env + [shlex.quote(w) for w in command(process)]))
        return 0
    return launch(desc, log_dir=args.log_dir, stop_timeout=args.stop_timeout)


def inspect_command(args: argparse.Namespace) -> int:
    """`ciml inspect --bag BAG [--out profile.yaml]`."""
    from ciml_learning.core.fileio import atomic_write_text
    from ciml_learning.logs.inspect_log import draft_profile, inspect_bag, profile_yaml

    robot = None
    if getattr(args, "robot", None) or getattr(args, "urdf", None):
        prof = profile_from_args(args)
        robot = prof.robot()
    feet = (tuple(robot.foot_frames) if robot is not None
            else tuple(args.feet) if getattr(args, "feet", None) else None)
    report = inspect_bag(args.bag, robot.joint_names if robot is not None else None, feet,
                         robot.total_mass if robot is not None else None)
    cmd = report["roles"].get("command", {}).get("spec", {})
    if robot is not None and "joints" in cmd and "joints" in prof.inputs.get("command", {}) and \
            prof.inputs["command"]["type"] == cmd["type"]:
        cmd["joints"] = list(prof.inputs["command"]["joints"])  # the given profile knows the array's order
    print(f"bag {report['bag']}")
    print(f"{'topic':40s} {'type':42s} {'count':>7s} {'rate_Hz':>8s}  stamp problems")
    for d in report["topics"]:
        rate = f"{d['rate_hz']:.1f}" if d.get("rate_hz") else "-"
        print(f"{d['topic']:40s} {d['type']:42s} {d['count']:7d} {rate:>8s}  {'; '.join(d['problems']) or 'ok'}")
    print("roles CIML can fill:")
    for role in ("joint_state", "base", "imu", "contacts", "command"):
        r = report["roles"].get(role)
        print(f"  {role:12s} {r['spec'] if r else '-'}")
        if r:
            print(f"  {'':12s} ({r['why']})")
    for n in report["notes"]:
        print(f"note: {n}")
    if args.out:
        urdf = robot.urdf_path if robot is not None else None
        name = os.path.splitext(os.path.basename(args.out))[0]
        atomic_write_text(args.out, profile_yaml(draft_profile(report, name, urdf, feet), report))
        print(f"draft profile: {args.out}")
    return 0
