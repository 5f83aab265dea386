"""The `ciml` verbs of ciml_sim (registered in setup.py, entry point group `ciml.verbs`):
record, closed-loop, verify and gap-bench simulate, and export-mjcf compiles with MuJoCo, so they live with
the simulator."""
from __future__ import annotations

import argparse

from ciml_learning.cli import args as ca
from ciml_learning.cli.args import Verb


def _record(s: argparse.ArgumentParser) -> None:
    s.add_argument("--scenario", type=ca.path, required=True, help="scenario YAML (unmodelled effects)")
    s.add_argument("--motion", required=True)
    s.add_argument("--duration", type=float, default=20.0, help="[s] (0, 3600]")
    s.add_argument("--seed", type=ca.integer(0, 2**32 - 1), default=0)
    s.add_argument("--out", type=ca.path, required=True, help="bag directory to create")
    s.add_argument("--no-ground-truth", action="store_true", help="leave the /sim/ topics out")
    s.add_argument("--sensor-rate", type=float, choices=(250.0, 500.0, 1000.0), default=250.0, metavar="HZ",
                   help="rate of the sensor topics (250, 500 or 1000 Hz; the controller and its "
                        "/torque_command stay at 250 Hz), for logs at a robot's own rate")


def _closed_loop(s: argparse.ArgumentParser) -> None:
    s.add_argument("--scenario", type=ca.path, required=True)
    s.add_argument("--motion", required=True)
    s.add_argument("--model", type=ca.path, required=True, help="MODEL_DIR, a diagnosis DIR, or 'nominal'")
    s.add_argument("--duration", type=float, default=None, help="[s] (0, 3600] (default: 10 gait cycles)")
    s.add_argument("--seed", type=ca.integer(0, 2**32 - 1), default=0)
    s.add_argument("--out", type=ca.path, required=True, help="result .json")
    s.add_argument("--report", type=ca.path, metavar="DIAG_DIR",
                   help="also add the result to the closed-loop comparison of this diagnosis report")


def _gap_bench(s: argparse.ArgumentParser) -> None:
    s.add_argument("--out", type=ca.path, required=True)
    s.add_argument("--cases", nargs="+", type=ca.integer(1, 10_000), help="run only these case numbers (1-based)")
    s.add_argument("--jobs", type=ca.jobs, default=1,
                   help="cases run in parallel (joblib; at most the cores available)")
    s.add_argument("--scale", type=ca.finite(0.01, 100), default=1.0, help="scale every recording's duration")
    s.add_argument("--random", type=ca.integer(1, 100_000), metavar="N",
                   help="N cases drawn at random from the effect registry's ranges instead of the suite")
    s.add_argument("--seed", type=ca.integer(0, 2**32 - 1), default=0, help="master seed of --random's draw")
    s.add_argument("--resume", action="store_true",
                   help="with --random: keep the cases --out already finished (same N and seed), run the rest")
    s.add_argument("--cluster", type=ca.cluster_address, metavar="ADDRESS",
                   help="run the cases on a Dask scheduler (tcp://HOST:8786) or on local:N, a LocalCluster of N "
                        "worker processes on 127.0.0.1, instead of --jobs")


def _verify(s: argparse.ArgumentParser) -> None:
    s.add_argument("--real", nargs="+", type=ca.path, required=True, metavar="BAG",
                   help="the real logs whose motions are re-simulated")
    s.add_argument("--diagnosis", type=ca.path, required=True, metavar="DIR",
                   help="a ciml diagnose folder (its identified_scenario.yaml)")
    s.add_argument("--oracle", type=ca.path, metavar="SCENARIO",
                   help="the true scenario, when known (benchmarks): the oracle column")
    s.add_argument("--motion", help="the motion of the bags that name none (no /reference, no recorded motion)")
    s.add_argument("--out", type=ca.path, required=True, help="folder for verify.json")


RECORD = Verb(
    help="simulate a motion headless and write an MCAP bag", arguments=_record,
    run="ciml_sim.commands:record", order=10,
    epilog="Writes what a robot logs (CIML's own topics) plus /sim/ ground truth unless --no-ground-truth.\n"
           "example: ciml record --scenario default_gap --motion trot_35 --duration 20 --seed 1 --out bags/t1")

CLOSED_LOOP = Verb(
    help="run a motion in simulation with a model and report tracking metrics", arguments=_closed_loop,
    run="ciml_sim.commands:closed_loop", order=50,
    epilog="Simulates the robot (MuJoCo) with the scenario's effects under the controller.\n"
           "example: ciml closed-loop --scenario default_gap --motion trot_35 --model model/ --out r.json")

GAP_BENCH = Verb(
    help="score the diagnosis on scenarios with withheld effects", arguments=_gap_bench,
    run="ciml_sim.gaprandom:command", order=70,
    epilog="Simulates scenarios with withheld effects and scores the diagnosis on them; its cases are "
           "HyQ's, so gap-bench takes no --robot.\n"
           "example: ciml gap-bench --out out/gap_bench --cases 1 2 --jobs 2\n"
           "         ciml gap-bench --out out/gap_random --random 20 --seed 1 --cluster local:2",
    no_robot="its cases are drawn on HyQ's joints and links (the suite's robot)")


def _export_mjcf(s: argparse.ArgumentParser) -> None:
    s.add_argument("--diagnosis", type=ca.path, required=True, help="a `ciml diagnose` output DIR")
    s.add_argument("--mjcf", type=ca.path, required=True, help="your MuJoCo model (MJCF .xml)")
    s.add_argument("--out", type=ca.path, required=True, help="the patched MJCF to write")


EXPORT_MJCF = Verb(
    help="write a diagnosis's effects into your MuJoCo model (MJCF)", arguments=_export_mjcf,
    run="ciml_sim.export_mjcf:export_mjcf_command", order=45,
    epilog="Joints, bodies and actuators are matched by name; sensor effects go to sensor_calibration.yaml "
           "beside --out.\n"
           "example: ciml export-mjcf --diagnosis diag/ --mjcf robot.xml --out robot_identified.xml",
    no_robot="the model is the MJCF given")

VERIFY = Verb(
    help="re-simulate the real logs' motions with the identified scenario: the gap before and after",
    arguments=_verify, run="ciml_sim.commands:verify", order=65,
    epilog="Re-records each log's motion in the simulator, nominal and with DIR/identified_scenario.yaml (and\n"
           "--oracle), and compares the extracted model error and the torques with the log's (docs/DIAGNOSIS.md).\n"
           "example: ciml verify --real bags/real_1 --diagnosis diag/ --out verify/")
