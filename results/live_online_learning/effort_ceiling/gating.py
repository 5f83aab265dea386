"""Research script (results/LIVE_GRAPH.md, thirteenth session): per model, the trust law's gating
counts and the RMS of the ε the controller used in a 15 s headless go1_gap trot.
    python gating.py PROFILE MODEL_DIR..."""
import argparse
import sys

import numpy as np

import ciml_sim.recorder as rec
from ciml_learning.cli.main import robot_from_args
from ciml_sim.commands import load_epsilon_function, scenario_for

made = []


class Capture(rec.TrustedEpsilonFunction):
    """The loop's trust law, keeping every ε it returns."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.eps = []
        made.append(self)

    def __call__(self, ref):
        e = super().__call__(ref)
        self.eps.append(np.array(e))
        return e


rec.TrustedEpsilonFunction = Capture
for model in sys.argv[2:]:
    args = argparse.Namespace(robot=sys.argv[1], urdf=None, scenario="go1_gap")
    robot = robot_from_args(args)
    r = rec.run_headless(robot, scenario_for(args, robot), "trot_35", 15.0, 11,
                         epsilon_fn=load_epsilon_function(robot, model), ground_truth=False, progress=False)
    E = np.array(made[-1].eps)
    print(model, f"effort {r.metrics()['rms_feedback_effort_nm']:.3f}", made[-1].counts,
          "rms eps joints", np.round(np.sqrt((E[:, 6:] ** 2).mean(0)), 2),
          "base", np.round(np.sqrt((E[:, :6] ** 2).mean(0)), 1), flush=True)
