"""The `ciml` verbs of ciml_learning (registered in setup.py, entry point group `ciml.verbs`).

Each verb names its options here and its implementation by import string, so `ciml --help`
imports none of the library. The simulator's verbs (record, closed-loop, gap-bench) are
registered by ciml_sim (ciml_sim/verbs.py).
"""
from __future__ import annotations

import argparse

from ciml_learning.cli import args as ca
from ciml_learning.cli.args import Verb

LOG = ("A log is a bag (rosbag2 MCAP or sqlite3 directory, or a ROS 1 .bag) holding what the robot "
       "profile's input map names: joint states (positions, velocities, efforts), the base (odometry, "
       "pose + twist, or an IMU to estimate it), contacts (a contact topic, foot forces, or estimated) "
       "and, optionally, the joint command (without it the actuation error is not observable). "
       "Default profile: HyQ with CIML's topics /joint_states, /base_state, /contact_state, "
       "/torque_command. See docs/ROBOT_PROFILE.md; 'ciml inspect --bag BAG' drafts a profile.")


def _extract(s: argparse.ArgumentParser) -> None:
    s.add_argument("--bag", type=ca.path, nargs="+", required=True)
    s.add_argument("--out", type=ca.path, required=True, help="targets .npz")


def _train(s: argparse.ArgumentParser) -> None:
    s.add_argument("--bag", type=ca.path, nargs="+", required=True)
    s.add_argument("--learner", choices=ca.RegistryNames("ciml_learning.learning.learners", "LEARNERS"), required=True,
                   metavar="LEARNER", help="one of %(choices)s")
    s.add_argument("--out", type=ca.path, required=True, help="model directory")
    s.add_argument("--jobs", type=ca.jobs, default=-1,
                   help="parallel jobs (joblib; -1: all cores; at most the cores available)")
    s.add_argument("--cluster", type=ca.cluster_address, metavar="ADDRESS",
                   help="fit the dimensions on a Dask scheduler (tcp://HOST:8786) or on local:N, a LocalCluster "
                        "of N processes on 127.0.0.1, instead of --jobs (README: running on a Dask cluster)")


def _evaluate(s: argparse.ArgumentParser) -> None:
    s.add_argument("--model", type=ca.path, required=True)
    s.add_argument("--bag", type=ca.path, nargs="+", required=True)
    s.add_argument("--out", type=ca.path, required=True, help="metrics .json")


def _diagnose(s: argparse.ArgumentParser) -> None:
    s.add_argument("--bag", type=ca.path, nargs="+", required=True)
    s.add_argument("--heldout", type=ca.path, nargs="+")
    s.add_argument("--reference", type=ca.path, nargs="+", metavar="REF_BAG",
                   help="logs of the same robot to compare with (e.g. the simulator's): also names what "
                        "distinguishes --bag from them (effects in one only, parameters that differ)")
    s.add_argument("--out", type=ca.path, required=True, help="output directory (diagnosis.json, report.html)")
    s.add_argument("--jobs", type=ca.jobs, default=-1,
                   help="bags read and filtered in parallel (joblib processes; -1: all cores; at most the cores "
                        "available)")
    s.add_argument("--cluster", type=ca.cluster_address, metavar="ADDRESS",
                   help="read and filter the bags on a Dask scheduler (tcp://HOST:8786) or on local:N, a "
                        "LocalCluster of N processes on 127.0.0.1, instead of --jobs (README: running on a Dask "
                        "cluster)")
    s.add_argument("--publish", type=ca.finite(0, 3600, " s"), nargs="?", const=5.0, default=None, metavar="SECONDS",
                   help="then publish the summary once on /gap_diagnosis (ciml_msgs/GapDiagnosis, transient local) "
                        "and keep it available for SECONDS (default 5)")


def _play(s: argparse.ArgumentParser) -> None:
    s.add_argument("--bag", type=ca.path, required=True)
    s.add_argument("--rate", type=ca.finite(0.001, 1000), default=1.0)


def _bench(s: argparse.ArgumentParser) -> None:
    s.add_argument("--out", type=ca.path, required=True, help="bench .json")
    s.add_argument("--only", nargs="+", help="run only these benchmarks")
    s.add_argument("--set", nargs="+", default=[], type=ca.assignment, metavar="NAME=VALUE",
                   help="options of the selected benchmarks, e.g. live_online_learning's seeds=0,1 duration=120")


def _launch(s: argparse.ArgumentParser) -> None:
    s.add_argument("file", type=ca.path,
                   help="launch file, or a package name followed by a file of its share/PKG/launch")
    s.add_argument("arguments", nargs="*", metavar="name:=value", help="launch arguments")
    s.add_argument("-s", "--show-args", action="store_true", help="list the file's arguments and exit")
    s.add_argument("--print", action="store_true",
                   help="print each process's command line (a node's, or a container's) and exit")
    s.add_argument("--log-dir", help="also write each process's output to LOG_DIR/<node or container>.log")
    s.add_argument("--stop-timeout", type=ca.finite(0, 3600, " s"), default=10.0,
                   help="[s] after SIGINT before SIGTERM")


def _inspect(s: argparse.ArgumentParser) -> None:
    s.add_argument("--bag", type=ca.path, required=True, help="bag directory (MCAP/db3) or ROS 1 .bag file")
    s.add_argument("--out", type=ca.path, metavar="PROFILE.yaml",
                   help="write a draft robot profile here (atomically)")


EXTRACT = Verb(
    help="filter logs and extract contact-invariant model errors", arguments=_extract,
    run="ciml_learning.cli.commands:extract", order=20,
    epilog=f"{LOG}\nexample: ciml --robot go1.yaml extract --bag run1 run2 --out targets.npz")

TRAIN = Verb(
    help="learn the model error from bags", arguments=_train,
    run="ciml_learning.cli.commands:train", order=30,
    epilog=f"{LOG}\nexample: ciml train --robot go1.yaml --bag run1 run2 --learner sgpr --out model/")

EVALUATE = Verb(
    help="prediction RMSE of a model on bags, nominal vs learned", arguments=_evaluate,
    run="ciml_learning.cli.commands:evaluate", order=40,
    epilog=f"MODEL_DIR as written by 'ciml train'. {LOG}\n"
           "example: ciml evaluate --model model/ --bag run3 --out metrics.json")

DIAGNOSE = Verb(
    help="where the sim-to-real gap lies, which effect causes it, how far it shrinks", arguments=_diagnose,
    run="ciml_learning.cli.commands:diagnose", order=60,
    epilog=f"{LOG} The logs should excite the joints (walking/trotting, ≥ 20 s in total).\n"
           "example: ciml diagnose --robot go1.yaml --bag run1 run2 --heldout run3 --out diag/")

PLAY = Verb(
    help="publish a bag onto the live ROS graph with its recorded timing", arguments=_play,
    run="ciml_learning.cli.commands:play", order=80,
    epilog="Publishes every topic of the bag (any layout) with its recorded timing; the nodes that read "
           "them take the robot (ciml launch ... robot:=go1), so play takes no --robot.\n"
           "example: ciml play --bag bags/default_gap_base --rate 1.0",
    no_robot="it publishes the bag's topics as recorded; give the robot to the nodes that read them "
             "(ciml --robot NAME launch FILE, or robot:=NAME)")

BENCH = Verb(
    help="speed and memory benchmarks (JSON)", arguments=_bench,
    run="ciml_learning.cli.commands:bench", order=90,
    epilog="Each benchmark simulates or reads its own robot and logs, so bench takes no --robot.\n"
           "example: ciml bench --out bench.json --only extraction_throughput",
    no_robot="each benchmark simulates or reads its own robot and logs")

LAUNCH = Verb(
    help="start the nodes of a YAML launch file (the file ros2 launch reads); a `containers` launch "
         "argument composes nodes in one process per group", arguments=_launch,
    run="ciml_learning.cli.commands:launch_command", order=100,
    epilog="--robot (a profile or a shipped robot's name) becomes the launch argument robot:=..., which "
           "the file must declare; --urdf and --feet likewise become urdf:= and feet:= (refused when "
           "the file declares no such argument).\n"
           "example: ciml launch ciml_sim closed_loop.launch.yaml motion:=trot_35 lockstep:=false "
           "(containers:='' starts one process per node)")

INSPECT = Verb(
    help="what a bag holds and which roles CIML can read from it; drafts a robot profile", arguments=_inspect,
    run="ciml_learning.cli.commands:inspect_command", order=110,
    epilog="Any bag: rosbag2 MCAP or sqlite3 directory, or a ROS 1 .bag. Lists topics, types, counts, "
           "measured rates and stamp problems, says which roles (joint_state, base, imu, contacts, "
           "command) CIML can fill from which topic, and with --out writes a draft profile to edit.\n"
           "example: ciml inspect --bag my_robot_run.bag --out my_robot.yaml")
