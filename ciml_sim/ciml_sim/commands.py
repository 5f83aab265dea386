"""Implementations of the simulation `ciml` verbs: `record` and `closed-loop` (docs/ARCHITECTURE.md §4).

Argument namespace in, exit code out; CimlErrors become one-line messages in ciml.cli.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Callable

import numpy as np

from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription


class ModelDirError(CimlError):
    """--model is neither 'nominal', a model directory nor a diagnosis directory."""


def _duration(value: float | None, what: str = "--duration") -> None:
    if value is not None and not (math.isfinite(value) and 0 < value <= 3600):
        raise CimlError(f"{what} must be in (0, 3600] seconds, got {value}")


def load_epsilon_function(robot: RobotDescription, spec: str) -> Callable | None:
    """The model error ε(reference point) the controller uses, from --model.

    'nominal' → None (ε = 0); a directory with diagnosis.json → the identified effects
    (ciml_learning.diagnosis); any other directory → a learned model (ciml_learning.learning.model_epsilon).
    """
    if spec == "nominal":
        return None
    if not os.path.isdir(spec):
        raise ModelDirError(f"--model {spec}: expected 'nominal', a model directory or a diagnosis directory")
    is_diagnosis = os.path.isfile(os.path.join(spec, "diagnosis.json"))
    module = "ciml_learning.diagnosis" if is_diagnosis else "ciml_learning.learning.model_epsilon"
    try:
        import importlib

        loader = importlib.import_module(module).load_epsilon_function
    except (ImportError, AttributeError) as err:
        raise ModelDirError(f"--model {spec}: {module}.load_epsilon_function is not available ({err})") from err
    try:
        return loader(robot, spec)
    except CimlError:
        raise
    except (OSError, ValueError, KeyError) as err:
        kind = "diagnosis" if is_diagnosis else "model"
        raise ModelDirError(f"--model {spec}: not a readable {kind} directory "
                            f"({type(err).__name__}: {' '.join(str(err).split())})") from err


def scenario_for(args: argparse.Namespace, robot: RobotDescription):
    """The --scenario for the robot of --robot; when it does not fit that robot (its joints or
    links are another robot's), the error names the shipped robots it fits: "add --robot go1"."""
    from ciml_learning.cli.main import profile_from_args
    from ciml_learning.core.profile import load_profile, shipped_names

    from .scenario import ScenarioError, resolve_scenario

    try:
        return resolve_scenario(args.scenario, robot)
    except ScenarioError as err:
        fits = []
        for name in shipped_names():
            if name == profile_from_args(args).name:
                continue
            try:
                resolve_scenario(args.scenario, load_profile(name).robot())
                fits.append(name)
            except CimlError:
                pass
        if fits:  # a robot the scenario is named after first (go1_gap: go1, then a1 with the same joints)
            fits.sort(key=lambda name: name not in os.path.basename(args.scenario))
            raise ScenarioError(f"{err} — scenario {args.scenario} is for robot {' or '.join(fits)}: add "
                                f"--robot {fits[0]}") from err
        raise


def record(args: argparse.Namespace) -> int:
    from ciml_learning.cli.main import robot_from_args

    from .recorder import check_motion, record_bag

    _duration(args.duration)
    if os.path.lexists(args.out):  # refused before the simulation, not after
        raise CimlError(f"{args.out} exists already; choose a new --out")
    from ciml_learning.core.fileio import check_out_parent

    check_out_parent(args.out, "--out")
    robot = robot_from_args(args)
    scenario = scenario_for(args, robot)
    check_motion(args.motion)
    result, counts = record_bag(robot, scenario, args.motion, args.duration, args.seed, args.out,
                                ground_truth=not args.no_ground_truth, sensor_rate=args.sensor_rate)
    metrics = result.metrics()
    # samples: the bag's joint-state samples (at the sensor rate); control_ticks: the controller's
    summary = {"out": args.out, "motion": args.motion, "duration_s": metrics["duration_s"],
               "sensor_rate_hz": args.sensor_rate, "samples": counts.get(topics.JOINT_STATES, 0),
               "control_ticks": metrics["samples"], "fell": metrics["fell"], "ground_truth": not args.no_ground_truth,
               "real_time_factor": metrics["real_time_factor"], "messages": sum(counts.values())}
    print(json.dumps(summary))
    if result.fell:
        print(f"ciml record: warning: the robot fell at t = {result.fall_time:.2f} s; the bag stops there",
              file=sys.stderr)
    return 0


def closed_loop(args: argparse.Namespace) -> int:
    from ciml_control.references import default_duration
    from ciml_learning.cli.main import robot_from_args
    from ciml_learning.core.fileio import atomic_write_json, check_out_dir, check_out_file
    from ciml_learning.diagnosis.files import is_diagnosis_dir

    from .recorder import check_motion, run_headless

    _duration(args.duration)
    check_out_file(args.out)
    if args.report:
        check_out_dir(args.report, is_diagnosis_dir, "diagnosis", "--report")
    robot = robot_from_args(args)
    scenario = scenario_for(args, robot)
    check_motion(args.motion)
    epsilon_fn = load_epsilon_function(robot, args.model)
    duration = args.duration if args.duration is not None else default_duration(args.motion)
    result = run_headless(robot, scenario, args.motion, duration, args.seed, epsilon_fn=epsilon_fn,
                          writer=None, ground_truth=False, progress=True)
    metrics = result.metrics()
    out = {"format_version": 1, "motion": args.motion, "model": args.model, "scenario": args.scenario,
           "seed": args.seed, "metrics": metrics}
    atomic_write_json(args.out, _jsonable(out))
    if args.report:
        _add_to_report(args.report, _model_label(args.model), _jsonable(metrics))
    print(json.dumps(_jsonable(metrics)))
    return 0


def _model_label(model: str) -> str:
    """How a model appears in the report's comparison: nominal / identified effects / learned."""
    if model == "nominal":
        return "nominal"
    if os.path.isfile(os.path.join(model, "diagnosis.json")):
        return "identified effects"
    from ciml_learning.core.fileio import load_json_bounded

    try:  # a label only: the model itself is verified when it is loaded
        meta = load_json_bounded(os.path.join(model, "model.json"), "model description", 16 * 2**20)
        return f"learned ({str(meta.get('learner', '?')).upper()})"
    except (CimlError, AttributeError):
        return os.path.basename(os.path.normpath(model))


def _add_to_report(diagnosis_dir: str, label: str, metrics: dict) -> None:
    """Add one closed-loop result to DIAG_DIR's comparison (diagnosis.json and report.html)."""
    from ciml_learning.diagnosis.files import read_diagnosis_json
    from ciml_learning.diagnosis.report import attach_closed_loop

    try:
        existing = read_diagnosis_json(diagnosis_dir).get("closed_loop") or {}
    except CimlError as err:
        raise CimlError(f"--report {diagnosis_dir}: no readable diagnosis.json ({err})") from None
    if not isinstance(existing, dict):
        existing = {}
    attach_closed_loop(diagnosis_dir, {**existing, label: metrics})


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


VERIFY_JSON = "verify.json"


def verify(args: argparse.Namespace) -> int:
    """`ciml verify --real BAGS... --diagnosis DIR [--oracle SCENARIO] [--motion NAME] --out DIR`:
    every input is checked before the first simulation; DIR/verify.json is written whole or not at all."""
    from ciml_learning.cli.main import robot_from_args
    from ciml_learning.core.fileio import atomic_dir, check_out_dir
    from ciml_learning.diagnosis.files import IDENTIFIED_SCENARIO, read_diagnosis_json

    from .scenario import load_scenario, resolve_scenario
    from .verify import check_logs, summary_lines
    from .verify import verify as run_verify

    def is_verify_dir(d: str) -> bool:
        return os.path.isfile(os.path.join(d, VERIFY_JSON))

    check_out_dir(args.out, is_verify_dir, "verify")
    scenario_path = os.path.join(args.diagnosis, IDENTIFIED_SCENARIO)
    if not os.path.isfile(scenario_path):
        raise CimlError(f"--diagnosis {args.diagnosis}: no {IDENTIFIED_SCENARIO} (ciml diagnose writes it); "
                        "verify re-simulates the identified scenario")
    robot = robot_from_args(args)
    identified = load_scenario(scenario_path, robot)
    oracle = resolve_scenario(args.oracle, robot) if args.oracle else None
    logs = check_logs(args.real, args.motion)
    try:  # the regression shrink (held-out residual, docs/DIAGNOSIS.md) stays beside the re-simulated one
        regression = read_diagnosis_json(args.diagnosis).get("shrink")
    except CimlError:
        regression = None
    result = run_verify(robot, logs, identified, oracle)
    doc = {"format_version": 1, "diagnosis": args.diagnosis, "identified_scenario": scenario_path,
           "oracle": args.oracle, **result, "regression_shrink": regression}
    with atomic_dir(args.out, is_verify_dir, "verify") as tmp:
        from ciml_learning.core.fileio import json_dumps

        with open(os.path.join(tmp, VERIFY_JSON), "w", encoding="utf-8") as f:
            f.write(json_dumps(_jsonable(doc)))
    for line in summary_lines(doc):
        print(line)
    print(f"ciml verify: {os.path.join(args.out, VERIFY_JSON)}")
    return 0
