"""The leg group's LWPR metric penalty γ against the online fade, and what it costs offline.

    python leg_penalty.py online ROBOT SCENARIO BAG PARAMS_JSON SEED   # BAG: 600 s trot_35, nominal controller
    python leg_penalty.py offline ROBOT SCENARIO BAG_DIR PARAMS_JSON
    python leg_penalty.py synthetic hyq - - GAMMA,...

ROBOT: a shipped profile name or a profile path (go1: ../go1_ciml_topics_profile.yaml, the bags are
on CIML's topics). PARAMS_JSON overrides ModelSet's LWPR defaults per group (e.g.
'{"leg": {"penalty": 1e-2}}'), or 'nominal' for no model.

online: the bag's samples are learned as the online learner gets them (go1_log.learner_rows)
through a streaming shuffle of 1,000 samples with rng SEED (go1_log.learning_order), by
partial_fit; after 1, 3 and 10 minutes of the log the model so far drives a closed loop
(trot_35 30 s, seed 11; RMS feedback effort [Nm]).
offline: `ciml train`'s fit of every bag in BAG_DIR (here the demo's nine 20 s recordings: `ciml
record [--robot …] --scenario SCENARIO --motion M --duration 20 --seed S` for M in base_only,
walk_35, trot_35 and S = 1, 2, 3); closed loops of 20 s, seed 11, on six motions, four of them
not trained on.
synthetic: test_models' check on ciml_learning's synthetic set (12 k samples, held-out 4 k of
another seed; sharp friction-like leg errors): the leg joints' RMSE against the truth [Nm] with
the leg group's γ set to each GAMMA.
"""
import glob
import json
import os
import sys

import numpy as np
from go1_log import learner_rows, learning_order

from ciml_learning.core.profile import load_profile, profile_path
from ciml_learning.learning.model_epsilon import EpsilonFunction
from ciml_learning.learning.models import ModelSet
from ciml_learning.logs.pipeline import load_dataset
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

mode, spec, scenario_name, data, params = sys.argv[1:6]
profile = load_profile(spec if spec.endswith(".yaml") else profile_path(spec))
robot = profile.robot()
scenario = None if mode == "synthetic" else resolve_scenario(scenario_name, robot)


def effort(ms, motion: str, duration: float) -> float:
    fn = None if ms is None else EpsilonFunction(robot, ms)
    return round(run_headless(robot, scenario, motion, duration, 11, epsilon_fn=fn,
                              progress=False).metrics()["rms_feedback_effort_nm"], 3)


if mode == "synthetic":
    from ciml_learning.learning.synthetic import fit_arguments, synthetic_training_set

    train, test = synthetic_training_set(robot, 12_000, seed=0), synthetic_training_set(robot, 4_000, seed=1)
    swing = test["generalized_observed"][:, 6:]
    for gamma in map(float, params.split(",")):
        ms = ModelSet.for_robot(robot, "lwpr", {"leg": {"penalty": gamma}}).fit(*fit_arguments(train))
        rbd = ms.predict(test["inputs"], return_var=False).rbd
        rmse = [float(np.sqrt(np.mean((rbd[swing[:, j], 6 + j] - test["rbd_true"][swing[:, j], 6 + j]) ** 2)))
                for j in range(swing.shape[1])]
        print(f"γ {gamma:g}: leg RMSE max {max(rmse):.2f} median {np.median(rmse):.2f} Nm", flush=True)
elif mode == "online":
    seed = int(sys.argv[6])
    if params == "nominal":
        print(f"{spec} nominal: effort {effort(None, 'trot_35', 30.0)}")
        sys.exit()
    tg = load_dataset(robot, [data], progress=False, profile=profile).targets
    rows = learner_rows(tg)
    order = learning_order(np.flatnonzero(rows), 1000, np.random.default_rng(seed))
    ms = ModelSet.for_robot(robot, "lwpr", json.loads(params))
    t = tg.t - tg.t[0]
    start = 0
    for minute in (1, 3, 10):
        end = int(np.sum(t[order] < 60.0 * minute))
        part = order[start:end]
        ms.partial_fit(tg.inputs[part], tg.generalized_error[part], tg.generalized_observed[part],
                       tg.actuation_error[part], tg.valid[part], tg.leg_coupling[part],
                       effort_valid=rows[part])
        start = end
        print(f"{spec} {params} seed {seed} after {minute} min: effort {effort(ms, 'trot_35', 30.0)}",
              flush=True)
else:
    motions = ("trot_35", "walk_20", "walk_rear_30", "walk_side_25", "trot_20", "trot_45")
    ms = None
    if params != "nominal":
        tg = load_dataset(robot, sorted(glob.glob(os.path.join(data, "*"))), progress=False,
                          profile=profile).targets
        ms = ModelSet.for_robot(robot, "lwpr", json.loads(params)).fit(
            tg.inputs, tg.generalized_error, tg.generalized_observed, tg.actuation_error, tg.valid,
            tg.leg_coupling, n_jobs=1, effort_valid=tg.effort_valid)
    print(spec, params, {m: effort(ms, m, 20.0) for m in motions}, flush=True)
