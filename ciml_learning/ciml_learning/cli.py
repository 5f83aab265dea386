"""`ciml`: the command line of CIML (DESIGN.md §4).

Each verb is a thin layer: parse arguments, call the library, write files atomically.
Expected failures (CimlError) print one line and exit 1.
"""
from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable

from .errors import CimlError

EXIT_ERROR = 1


def _run(module: str, function: str) -> Callable[[argparse.Namespace], int]:
    """Import the verb's implementation only when it runs (keeps `ciml --help` fast)."""

    def call(args: argparse.Namespace) -> int:
        import importlib

        return getattr(importlib.import_module(module), function)(args)

    return call


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ciml",
        description="Contact-invariant model learning for legged robots: learn a robot's model "
        "error from sensor logs, control with it, and diagnose the sim-to-real gap.",
    )
    p.add_argument("--urdf", help="robot URDF (default: HyQ from example-robot-data)")
    p.add_argument("--feet", nargs="+", help="foot frame names of the URDF (default: HyQ's)")
    sub = p.add_subparsers(dest="verb", metavar="VERB", required=True)

    s = sub.add_parser("record", help="simulate a motion headless and write an MCAP bag")
    s.add_argument("--scenario", required=True, help="scenario YAML (unmodelled effects)")
    s.add_argument("--motion", required=True)
    s.add_argument("--duration", type=float, default=20.0, help="[s]")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", required=True, help="bag directory to create")
    s.add_argument("--no-ground-truth", action="store_true", help="leave the /sim/ topics out")
    s.set_defaults(func=_run("ciml_sim.commands", "record"))

    s = sub.add_parser("extract", help="filter logs and extract contact-invariant model errors")
    s.add_argument("--bag", nargs="+", required=True)
    s.add_argument("--out", required=True, help="targets .npz")
    s.set_defaults(func=_run("ciml_learning.commands", "extract"))

    s = sub.add_parser("train", help="learn the model error from bags")
    s.add_argument("--bag", nargs="+", required=True)
    s.add_argument("--learner", choices=("lwpr", "sgpr"), required=True)
    s.add_argument("--out", required=True, help="model directory")
    s.add_argument("--jobs", type=int, default=-1, help="parallel jobs (joblib; -1: all cores)")
    s.set_defaults(func=_run("ciml_learning.learning_commands", "train"))

    s = sub.add_parser("evaluate", help="prediction RMSE of a model on bags, nominal vs learned")
    s.add_argument("--model", required=True)
    s.add_argument("--bag", nargs="+", required=True)
    s.add_argument("--out", required=True, help="metrics .json")
    s.set_defaults(func=_run("ciml_learning.learning_commands", "evaluate"))

    s = sub.add_parser("closed-loop", help="run a motion in simulation with a model and report tracking metrics")
    s.add_argument("--scenario", required=True)
    s.add_argument("--motion", required=True)
    s.add_argument("--model", required=True, help="MODEL_DIR, a diagnosis DIR, or 'nominal'")
    s.add_argument("--duration", type=float, default=None, help="[s] (default: 10 gait cycles)")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--out", required=True, help="result .json")
    s.add_argument("--report", metavar="DIAG_DIR",
                   help="also add the result to the closed-loop comparison of this diagnosis report")
    s.set_defaults(func=_run("ciml_sim.commands", "closed_loop"))

    s = sub.add_parser("diagnose", help="where the sim-to-real gap lies, which effect causes it, how far it shrinks")
    s.add_argument("--bag", nargs="+", required=True)
    s.add_argument("--heldout", nargs="+")
    s.add_argument("--out", required=True, help="output directory (diagnosis.json, report.html)")
    s.set_defaults(func=_run("ciml_learning.diagnosis.commands", "diagnose"))

    s = sub.add_parser("gap-bench", help="score the diagnosis on scenarios with withheld effects")
    s.add_argument("--out", required=True)
    s.add_argument("--cases", nargs="+", type=int, help="run only these case numbers (1-based)")
    s.add_argument("--jobs", type=int, default=1, help="cases run in parallel (joblib)")
    s.add_argument("--scale", type=float, default=1.0, help="scale every recording's duration")
    s.set_defaults(func=_run("ciml_sim.gapbench", "gap_bench_command"))

    s = sub.add_parser("play", help="publish a bag onto the live ROS graph with its recorded timing")
    s.add_argument("--bag", required=True)
    s.add_argument("--rate", type=float, default=1.0)
    s.set_defaults(func=_run("ciml_learning.commands", "play"))

    s = sub.add_parser("bench", help="speed and memory benchmarks (JSON)")
    s.add_argument("--out", required=True, help="bench .json")
    s.add_argument("--only", nargs="+", help="run only these benchmarks")
    s.set_defaults(func=_run("ciml_learning.commands", "bench"))

    s = sub.add_parser("launch", help="start the nodes of a YAML launch file (the file ros2 launch reads)")
    s.add_argument("file", help="launch file, or a package name followed by a file of its share/PKG/launch")
    s.add_argument("arguments", nargs="*", metavar="name:=value", help="launch arguments")
    s.add_argument("-s", "--show-args", action="store_true", help="list the file's arguments and exit")
    s.add_argument("--print", action="store_true", help="print each node's command line and exit")
    s.add_argument("--log-dir", help="also write each node's output to LOG_DIR/<node>.log")
    s.add_argument("--stop-timeout", type=float, default=10.0, help="[s] after SIGINT before SIGTERM")
    s.set_defaults(func=_run("ciml_learning.launcher", "launch_command"))
    return p


def main(argv: list[str] | None = None) -> int:
    # DDS stays on this machine unless the user explicitly widens it (e.g. SUBNET).
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except CimlError as err:
        print(f"ciml {args.verb}: error: {str(err).splitlines()[0] if str(err) else type(err).__name__}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"ciml {args.verb}: interrupted", file=sys.stderr)
        return 130


def robot_from_args(args: argparse.Namespace):
    from .robot import load_robot

    return load_robot(getattr(args, "urdf", None), getattr(args, "feet", None))


if __name__ == "__main__":
    sys.exit(main())
