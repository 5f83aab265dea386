"""Headless closed loop (ciml_sim.recorder.run_headless: deterministic, no ROS) with one fixed snapshot of the
live learner, and for BAD_LEN seconds from BAD_FROM its ε × K (K = 1: no perturbation). Prints the RMS feedback
effort per 5 s: is a fixed model's effort stationary, and does it return to its level after a bad model's seconds?
usage: hyst.py SNAPSHOT DURATION BAD_FROM BAD_LEN K (results/LIVE_GRAPH.md, seventeenth session)"""
import sys, json, numpy as np
from ciml_learning.profile import load_profile
from ciml_learning.model_epsilon import load_epsilon_function
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario
robot = load_profile("hyq").robot()
snap, duration, t_bad, n_bad, k = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5])
good = load_epsilon_function(robot, snap)
t0 = [None]
def eps(ref):
    if t0[0] is None: t0[0] = float(ref.t)
    e = good(ref)
    return k * e if t_bad <= float(ref.t) - t0[0] < t_bad + n_bad else e
r = run_headless(robot, resolve_scenario("default_gap", robot), "trot_35", duration, 0, epsilon_fn=eps, writer=None,
                 ground_truth=False, progress=False)
e = np.asarray(r.feedback_effort); per = int(250 * 5)
print(json.dumps({"snapshot": snap.split('/')[-1], "bad_from_s": t_bad, "bad_len_s": n_bad, "k": k, "fell": bool(r.fell),
                  "rms_per_5s": [round(float(np.sqrt(np.mean(e[i:i+per]**2))), 1) for i in range(0, len(e), per)]}))
