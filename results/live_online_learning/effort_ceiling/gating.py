"""Per-model trust gating and ε in the headless go1_gap loop: python gating.py PROFILE MODEL..."""
import argparse, sys
import numpy as np
import ciml_sim.recorder as rec
from ciml_sim.commands import load_epsilon_function, scenario_for
from ciml_learning.cli import robot_from_args

made = []
class Capture(rec.TrustedEpsilonFunction):
    def __init__(self, *a, **k):
        super().__init__(*a, **k); self.eps = []; made.append(self)
    def __call__(self, ref):
        e = super().__call__(ref); self.eps.append(np.array(e)); return e
rec.TrustedEpsilonFunction = Capture
for model in sys.argv[2:]:
    args = argparse.Namespace(robot=sys.argv[1], urdf=None, scenario="go1_gap")
    robot = robot_from_args(args)
    r = rec.run_headless(robot, scenario_for(args, robot), "trot_35", 15.0, 11,
                         epsilon_fn=load_epsilon_function(robot, model), ground_truth=False, progress=False)
    t = made[-1]; E = np.array(t.eps)
    print(model, "effort %.3f" % r.metrics()["rms_feedback_effort_nm"], t.counts,
          "rms eps joints", np.round(np.sqrt((E[:, 6:] ** 2).mean(0)), 2), "base", np.round(np.sqrt((E[:, :6] ** 2).mean(0)), 1), flush=True)
