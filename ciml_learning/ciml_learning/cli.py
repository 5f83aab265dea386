"""`ciml`: the command line of CIML (docs/ARCHITECTURE.md §4).

Each verb is a thin layer: parse arguments, call the library, write files atomically.
Expected failures (CimlError) print one line and exit 1.
"""
from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable

from . import cliargs as ca
from .errors import CimlError

EXIT_ERROR = 1
EXIT_INTERNAL = 70
"""A bug, not bad input (sysexits EX_SOFTWARE): one line, the traceback with CIML_DEBUG=1."""


def _run(module: str, function: str) -> Callable[[argparse.Namespace], int]:
    """Import the verb's implementation only when it runs (keeps `ciml --help` fast)."""

    def call(args: argparse.Namespace) -> int:
        import importlib

        return getattr(importlib.import_module(module), function)(args)

    return call


_LOG = ("A log is a bag (rosbag2 MCAP or sqlite3 directory, or a ROS 1 .bag) holding what the robot "
        "profile's input map names: joint states (positions, velocities, efforts), the base (odometry, "
        "pose + twist, or an IMU to estimate it), contacts (a contact topic, foot forces, or estimated) "
        "and, optionally, the joint command (without it the actuation error is not observable). "
        "Default profile: HyQ with CIML's topics /joint_states, /base_state, /contact_state, "
        "/torque_command. See docs/ROBOT_PROFILE.md; 'ciml inspect --bag BAG' drafts a profile.")

EPILOGS: dict[str, str] = {
    "record": "Writes what a robot logs (CIML's own topics) plus /sim/ ground truth unless --no-ground-truth.\n"
              "example: ciml record --scenario default_gap --motion trot_35 --duration 20 --seed 1 --out bags/t1",
    "extract": f"{_LOG}\nexample: ciml --robot go1.yaml extract --bag run1 run2 --out targets.npz",
    "train": f"{_LOG}\nexample: ciml train --robot go1.yaml --bag run1 run2 --learner sgpr --out model/",
    "evaluate": f"MODEL_DIR as written by 'ciml train'. {_LOG}\n"
                "example: ciml evaluate --model model/ --bag run3 --out metrics.json",
    "closed-loop": "Simulates the robot (MuJoCo) with the scenario's effects under the controller.\n"
                   "example: ciml closed-loop --scenario default_gap --motion trot_35 --model model/ --out r.json",
    "diagnose": f"{_LOG} The logs should excite the joints (walking/trotting, ≥ 20 s in total).\n"
                "example: ciml diagnose --robot go1.yaml --bag run1 run2 --heldout run3 --out diag/",
    "gap-bench": "Simulates scenarios with withheld effects and scores the diagnosis on them.\n"
                 "example: ciml gap-bench --out out/gap_bench --cases 1 2 --jobs 2",
    "play": "Publishes every topic of the bag (any layout) with its recorded timing.\n"
            "example: ciml play --bag bags/default_gap_base --rate 1.0",
    "bench": "example: ciml bench --out bench.json --only extraction_throughput",
    "launch": "example: ciml launch ciml_sim closed_loop.launch.yaml motion:=trot_35",
    "inspect": "Any bag: rosbag2 MCAP or sqlite3 directory, or a ROS 1 .bag. Lists topics, types, counts, "
               "measured rates and stamp problems, says which roles (joint_state, base, imu, contacts, "
               "command) CIML can fill from which topic, and with --out writes a draft profile to edit.\n"
               "example: ciml inspect --bag my_robot_run.bag --out my_robot.yaml",
}


def _feet(value: str) -> list[str]:
    """--feet 'A,B,C,D' (or A B C D, joined by _join_feet) → names."""
    names = [f.strip() for f in value.split(",") if f.strip()]
    if not names:
        raise argparse.ArgumentTypeError("--feet needs foot frame names, e.g. --feet lf_foot,lh_foot,rf_foot,rh_foot")
    return names


def _global_options(parser: argparse.ArgumentParser, suppress: bool) -> None:
    """--robot, --urdf, --feet: accepted before and after the verb (after the verb they
    default to SUPPRESS so they do not overwrite what was given before it)."""
    d = {"default": argparse.SUPPRESS} if suppress else {"default": None}
    g = parser.add_argument_group("robot (before or after the verb)")
    g.add_argument("--robot", metavar="PROFILE.yaml", help="robot profile: URDF, feet, joint map, input map "
                   "(default: HyQ with CIML's own topics; docs/ROBOT_PROFILE.md)", **d)
    g.add_argument("--urdf", help="robot URDF (shortcut: overrides the profile's urdf)", **d)
    g.add_argument("--feet", type=_feet, metavar="A,B,C,D",
                   help="foot frame names of the URDF, comma-separated or space-separated "
                   "(overrides the profile's feet)", **d)


def _join_feet(argv: list[str], verbs: set[str]) -> list[str]:
    """`--feet A B C D` → `--feet=A,B,C,D`, so the names never swallow the verb."""
    out, i = [], 0
    while i < len(argv):
        if argv[i] == "--feet":
            j = i + 1
            while j < len(argv) and not argv[j].startswith("-") and argv[j] not in verbs:
                j += 1
            out.append("--feet=" + ",".join(argv[i + 1:j]) if j > i + 1 else argv[i])
            i = j
        else:
            out.append(argv[i])
            i += 1
    return out


def build_parser() -> argparse.ArgumentParser:
    p = ca.OneLineParser(
        prog="ciml",
        description="Contact-invariant model learning for legged robots: learn a robot's model "
        "error from sensor logs, control with it, and diagnose the sim-to-real gap.",
    )
    _global_options(p, suppress=False)
    sub = p.add_subparsers(dest="verb", metavar="VERB", required=True)
    parent = argparse.ArgumentParser(add_help=False)
    _global_options(parent, suppress=True)

    def verb(name: str, **kw) -> argparse.ArgumentParser:
        import textwrap

        # paragraphs wrapped here, example lines kept whole (RawDescription keeps them as given)
        epilog = "\n".join(textwrap.fill(par, 100, break_on_hyphens=False) if not par.startswith("example:")
                            else par for par in EPILOGS.get(name, "").split("\n")) or None
        return sub.add_parser(name, parents=[parent], epilog=epilog,
                              formatter_class=argparse.RawDescriptionHelpFormatter, **kw)

    s = verb("record", help="simulate a motion headless and write an MCAP bag")
    s.add_argument("--scenario", type=ca.path, required=True, help="scenario YAML (unmodelled effects)")
    s.add_argument("--motion", required=True)
    s.add_argument("--duration", type=float, default=20.0, help="[s] (0, 3600]")
    s.add_argument("--seed", type=ca.integer(0, 2**32 - 1), default=0)
    s.add_argument("--out", type=ca.path, required=True, help="bag directory to create")
    s.add_argument("--no-ground-truth", action="store_true", help="leave the /sim/ topics out")
    s.set_defaults(func=_run("ciml_sim.commands", "record"))

    s = verb("extract", help="filter logs and extract contact-invariant model errors")
    s.add_argument("--bag", type=ca.path, nargs="+", required=True)
    s.add_argument("--out", type=ca.path, required=True, help="targets .npz")
    s.set_defaults(func=_run("ciml_learning.commands", "extract"))

    s = verb("train", help="learn the model error from bags")
    s.add_argument("--bag", type=ca.path, nargs="+", required=True)
    s.add_argument("--learner", choices=("lwpr", "sgpr"), required=True)
    s.add_argument("--out", type=ca.path, required=True, help="model directory")
    s.add_argument("--jobs", type=ca.jobs, default=-1, help="parallel jobs (joblib; -1: all cores; at most the cores available)")
    s.set_defaults(func=_run("ciml_learning.learning_commands", "train"))

    s = verb("evaluate", help="prediction RMSE of a model on bags, nominal vs learned")
    s.add_argument("--model", type=ca.path, required=True)
    s.add_argument("--bag", type=ca.path, nargs="+", required=True)
    s.add_argument("--out", type=ca.path, required=True, help="metrics .json")
    s.set_defaults(func=_run("ciml_learning.learning_commands", "evaluate"))

    s = verb("closed-loop", help="run a motion in simulation with a model and report tracking metrics")
    s.add_argument("--scenario", type=ca.path, required=True)
    s.add_argument("--motion", required=True)
    s.add_argument("--model", type=ca.path, required=True, help="MODEL_DIR, a diagnosis DIR, or 'nominal'")
    s.add_argument("--duration", type=float, default=None, help="[s] (0, 3600] (default: 10 gait cycles)")
    s.add_argument("--seed", type=ca.integer(0, 2**32 - 1), default=0)
    s.add_argument("--out", type=ca.path, required=True, help="result .json")
    s.add_argument("--report", type=ca.path, metavar="DIAG_DIR",
                   help="also add the result to the closed-loop comparison of this diagnosis report")
    s.set_defaults(func=_run("ciml_sim.commands", "closed_loop"))

    s = verb("diagnose", help="where the sim-to-real gap lies, which effect causes it, how far it shrinks")
    s.add_argument("--bag", type=ca.path, nargs="+", required=True)
    s.add_argument("--heldout", type=ca.path, nargs="+")
    s.add_argument("--reference", type=ca.path, nargs="+", metavar="REF_BAG",
                   help="logs of the same robot to compare with (e.g. the simulator's): also names what "
                        "distinguishes --bag from them (effects in one only, parameters that differ)")
    s.add_argument("--out", type=ca.path, required=True, help="output directory (diagnosis.json, report.html)")
    s.add_argument("--publish", type=ca.finite(0, 3600, " s"), nargs="?", const=5.0, default=None, metavar="SECONDS",
                   help="then publish the summary once on /gap_diagnosis (ciml_msgs/GapDiagnosis, transient local) "
                        "and keep it available for SECONDS (default 5)")
    s.set_defaults(func=_run("ciml_learning.diagnosis.commands", "diagnose"))

    s = verb("gap-bench", help="score the diagnosis on scenarios with withheld effects")
    s.add_argument("--out", type=ca.path, required=True)
    s.add_argument("--cases", nargs="+", type=ca.integer(1, 10_000), help="run only these case numbers (1-based)")
    s.add_argument("--jobs", type=ca.jobs, default=1, help="cases run in parallel (joblib; at most the cores available)")
    s.add_argument("--scale", type=ca.finite(0.01, 100), default=1.0, help="scale every recording's duration")
    s.set_defaults(func=_run("ciml_sim.gapbench", "gap_bench_command"))

    s = verb("play", help="publish a bag onto the live ROS graph with its recorded timing")
    s.add_argument("--bag", type=ca.path, required=True)
    s.add_argument("--rate", type=ca.finite(0.001, 1000), default=1.0)
    s.set_defaults(func=_run("ciml_learning.commands", "play"))

    s = verb("bench", help="speed and memory benchmarks (JSON)")
    s.add_argument("--out", type=ca.path, required=True, help="bench .json")
    s.add_argument("--only", nargs="+", help="run only these benchmarks")
    s.set_defaults(func=_run("ciml_learning.commands", "bench"))

    s = verb("launch", help="start the nodes of a YAML launch file (the file ros2 launch reads)")
    s.add_argument("file", type=ca.path, help="launch file, or a package name followed by a file of its share/PKG/launch")
    s.add_argument("arguments", nargs="*", metavar="name:=value", help="launch arguments")
    s.add_argument("-s", "--show-args", action="store_true", help="list the file's arguments and exit")
    s.add_argument("--print", action="store_true", help="print each node's command line and exit")
    s.add_argument("--log-dir", help="also write each node's output to LOG_DIR/<node>.log")
    s.add_argument("--stop-timeout", type=ca.finite(0, 3600, " s"), default=10.0, help="[s] after SIGINT before SIGTERM")
    s.set_defaults(func=_run("ciml_learning.launcher", "launch_command"))

    s = verb("inspect", help="what a bag holds and which roles CIML can read from it; drafts a robot profile")
    s.add_argument("--bag", type=ca.path, required=True, help="bag directory (MCAP/db3) or ROS 1 .bag file")
    s.add_argument("--out", type=ca.path, metavar="PROFILE.yaml", help="write a draft robot profile here (atomically)")
    s.set_defaults(func=_run("ciml_learning.inspect_log", "inspect_command"))
    return p


def main(argv: list[str] | None = None) -> int:
    # DDS stays on this machine unless the user explicitly widens it (e.g. SUBNET).
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    parser = build_parser()
    verbs = set(next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices)
    args = parser.parse_args(_join_feet(list(sys.argv[1:] if argv is None else argv), verbs))
    try:
        return int(args.func(args) or 0)
    except CimlError as err:
        print(ca.one_line(f"ciml {args.verb}: error: {str(err).strip() or type(err).__name__}"), file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        print(f"ciml {args.verb}: interrupted", file=sys.stderr)
        return 130
    except (OSError, MemoryError) as err:  # the system refused something no check foresaw: still one line
        where = f" ({err.filename})" if isinstance(err, OSError) and err.filename else ""
        what = (err.strerror if isinstance(err, OSError) else None) or str(err) or type(err).__name__
        print(ca.one_line(f"ciml {args.verb}: error: {' '.join(what.split())}{where}"), file=sys.stderr)
        return EXIT_ERROR
    except Exception as err:  # a bug: one line here, the traceback with CIML_DEBUG=1
        if os.environ.get("CIML_DEBUG"):
            raise
        msg = ca.one_line(str(err), 300)
        print(ca.one_line(f"ciml {args.verb}: internal error: {type(err).__name__}: {msg} (run with CIML_DEBUG=1 "
                          "for the traceback)"), file=sys.stderr)
        return EXIT_INTERNAL


def profile_from_args(args: argparse.Namespace):
    """The robot profile of --robot (default: HyQ) with the --urdf/--feet shortcuts applied."""
    cached = getattr(args, "_profile", None)
    if cached is not None:
        return cached
    from .profile import load_profile, with_overrides

    prof = with_overrides(load_profile(getattr(args, "robot", None)), getattr(args, "urdf", None),
                          getattr(args, "feet", None))
    args._profile = prof
    return prof


def robot_from_args(args: argparse.Namespace):
    """The RobotDescription of --robot / --urdf / --feet (profile's torque limits applied)."""
    cached = getattr(args, "_robot", None)
    if cached is None:
        cached = profile_from_args(args).robot()
        args._robot = cached
    return cached


if __name__ == "__main__":
    sys.exit(main())
