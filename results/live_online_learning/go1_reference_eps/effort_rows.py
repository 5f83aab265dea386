"""Closed-loop feedback effort of LWPR models whose actuation part Γ learns from different rows.

    python effort_rows.py ROBOT BAG SCENARIO EVERY,...   # ROBOT: a shipped name or a profile path

One bag (its profile's layout), `ciml train`'s extraction; per model, closed loop trot_35 30 s,
seed 11 (RMS feedback effort [Nm]). EVERY 0: Γ from the valid rows only (before
FilteredLog.effort_valid); k ≥ 1: the valid rows plus every k-th of those valid for Γ only (near a
contact change); 1 is what `ciml train` does, 4 what the live error extractor sends by default.
"""
import sys

import numpy as np

from ciml_learning.core.profile import load_profile, profile_path
from ciml_learning.learning.model_epsilon import EpsilonFunction
from ciml_learning.learning.models import ModelSet
from ciml_learning.logs.pipeline import load_dataset
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

spec, bag, scenario_name, everies = sys.argv[1:5]
profile = load_profile(spec if spec.endswith(".yaml") else profile_path(spec))
robot = profile.robot()
tg = load_dataset(robot, [bag], progress=False, profile=profile).targets
scenario = resolve_scenario(scenario_name, robot)


def effort(ms):
    fn = None if ms is None else EpsilonFunction(robot, ms)
    return round(run_headless(robot, scenario, "trot_35", 30.0, 11, epsilon_fn=fn,
                              progress=False).metrics()["rms_feedback_effort_nm"], 3)


print("nominal", effort(None), flush=True)
for every in (int(k) for k in everies.split(",")):
    rows = tg.valid if every == 0 else tg.valid | (tg.effort_valid & (np.arange(len(tg.valid)) % every == 0))
    ms = ModelSet.for_robot(robot, "lwpr").fit(tg.inputs, tg.generalized_error, tg.generalized_observed,
                                              tg.actuation_error, tg.valid, tg.leg_coupling, n_jobs=2,
                                              effort_valid=rows)
    print(f"Γ rows: {'valid only' if every == 0 else f'valid + every {every}'} ({int(rows.sum())} of {len(rows)}):"
          f" effort {effort(ms)}", flush=True)
