#!/usr/bin/env python3
"""Study: which inputs the rigid-body models read, measured in closed loop.

Trains a model set whose base-wrench and leg-joint models read a chosen input set (the
product's `models.rbd_input_names` or a variant), then runs the closed loop of every
motion of tools/experiment.py (default gap, seed 1001, 10 gait cycles) and prints the
RMS feedback effort and its reduction vs nominal, per motion and as the two means.

    python results/experiment_studies/input_study.py BAG_DIR VARIANT [--learner lwpr|sgpr] [--work DIR]

BAG_DIR: the training recordings of tools/experiment.py (`<work>/bags`, the *_<rep> ones).
VARIANT: LEGS+BASE, LEGS one of product, qd, q_qd (a leg joint's own q̇; q and q̇);
BASE one of product, format4 (roll, pitch, q̇_base, q̈_base), nolin (no linear base
velocity), novel (no base velocity), e.g. `q_qd+format4`. A study script, not product.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "tools"))
from experiment import NEW_MOTIONS, ROOT, SCENARIO, TRAIN_MOTIONS  # noqa: E402  (tools/experiment.py)

from ciml_control.references import default_duration
from ciml_learning.core.physical_bounds import N_BASE
from ciml_learning.core.robot import load_robot
from ciml_learning.learning.model_epsilon import load_epsilon_function
from ciml_learning.learning.models import ModelSet, joint_state_names, rbd_input_names
from ciml_learning.logs.pipeline import load_dataset
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario


def variant_inputs(robot, variant: str) -> dict[str, tuple[str, ...]]:
    legs, _, base = variant.partition("+")
    base = base or "product"
    out = rbd_input_names(robot)
    dofs = robot.dof_names[:N_BASE]
    format4 = ("base_roll", "base_pitch") + tuple(f"qd_{d}" for d in dofs) + tuple(f"qdd_{d}" for d in dofs)
    bases = {"product": None, "format4": format4,
             "nolin": ("base_roll", "base_pitch") + tuple(f"qd_{d}" for d in dofs[3:])
                      + tuple(f"qdd_{d}" for d in dofs),
             "novel": ("base_roll", "base_pitch") + tuple(f"qdd_{d}" for d in dofs)}
    if bases[base] is not None:
        out.update({name: bases[base] for name in robot.rbd_error_names[:N_BASE]})
    for joint in robot.joint_names:
        q, qd, _ = joint_state_names(joint)
        choice = {"product": None, "qd": (qd,), "q_qd": (q, qd)}[legs]
        if choice is not None:
            out[f"rbd_{joint}"] = choice
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("bag_dir")
    p.add_argument("variant")
    p.add_argument("--learner", default="lwpr", choices=("lwpr", "sgpr"))
    p.add_argument("--work", default=os.path.join(ROOT, "out", "input_study"))
    args = p.parse_args()
    robot = load_robot()
    bags = sorted(glob.glob(os.path.join(args.bag_dir, "*_[0-9]")))
    inputs = variant_inputs(robot, args.variant)
    model_dir = os.path.join(args.work, f"model_{args.variant}_{args.learner}")
    tg = load_dataset(robot, bags, progress=False).targets
    empty = ModelSet.for_robot(robot, args.learner)
    ms = ModelSet(args.learner, empty.input_names, empty.rbd_names, empty.joint_names, empty.foot_frames, None, inputs)
    ms.fit(tg.inputs, tg.generalized_error, tg.generalized_observed, tg.actuation_error, tg.valid, tg.leg_coupling,
           n_jobs=-1)
    ms.training_ = {"bags": bags}
    os.makedirs(args.work, exist_ok=True)
    ms.save(model_dir)

    scenario = resolve_scenario(SCENARIO, robot)
    nominal_file = os.path.join(args.work, "nominal.json")
    nominal = {}
    if os.path.exists(nominal_file):
        with open(nominal_file, encoding="utf-8") as f:
            nominal = json.load(f)
    eps = load_epsilon_function(robot, model_dir)
    reduction = {}
    for motion in TRAIN_MOTIONS + NEW_MOTIONS:
        if motion not in nominal:
            nominal[motion] = run_headless(robot, scenario, motion, default_duration(motion), 1001,
                                           progress=False).metrics()["rms_feedback_effort_nm"]
        learned = run_headless(robot, scenario, motion, default_duration(motion), 1001, epsilon_fn=eps,
                               progress=False).metrics()["rms_feedback_effort_nm"]
        reduction[motion] = 1 - learned / nominal[motion]
        print(f"{motion:14s} nominal {nominal[motion]:6.2f}  learned {learned:6.2f}  {100 * reduction[motion]:5.1f} %",
              flush=True)
    with open(nominal_file, "w", encoding="utf-8") as f:
        json.dump(nominal, f)
    print(f"{args.variant} {args.learner}: training {100 * np.mean([reduction[m] for m in TRAIN_MOTIONS]):.1f} %, "
          f"new {100 * np.mean([reduction[m] for m in NEW_MOTIONS]):.1f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
