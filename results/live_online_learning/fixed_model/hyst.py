"""Headless closed loop (ciml_sim.recorder.run_headless: deterministic, no ROS) with one fixed snapshot of the
live learner under the controller's trust law, and for BAD_LEN seconds from BAD_FROM its predictions × K
(K = 1: no perturbation). Prints the RMS feedback effort and tracking errors per 5 s: is a fixed model's
effort stationary, and does it return to its level after a bad model's seconds?
usage: hyst.py SNAPSHOT DURATION BAD_FROM BAD_LEN K [OUTSIDE] (OUTSIDE: the factor outside those seconds, default 1;
0: the nominal model with a kick of the snapshot; results/LIVE_GRAPH.md, seventeenth session)"""
import json
import os
import sys

import numpy as np

from ciml_learning.core.profile import load_profile
from ciml_learning.learning.model_epsilon import load_epsilon_function
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

PER = 250 * 5  # commands per 5 s at the control rate


def main() -> None:
    robot = load_profile("hyq").robot()
    snap = sys.argv[1]
    duration, t_bad, n_bad, k = (float(a) for a in sys.argv[2:6])
    outside = float(sys.argv[6]) if len(sys.argv) > 6 else 1.0
    good = load_epsilon_function(robot, snap)
    start: list[float] = []

    class Perturbed:
        """The snapshot's predictions, their means × K in the bad seconds; with `model_set` and
        `predict`, so run_headless applies the live controller's trust law (variance gate, clip)."""

        model_set = good.model_set

        def predict(self, ref):
            if not start:
                start.append(float(ref.t))
            out = good.predict(ref)
            if out is None:
                return out
            f = k if t_bad <= float(ref.t) - start[0] < t_bad + n_bad else outside
            rbd, rbd_var, gamma, gamma_var = out
            return f * rbd, rbd_var, f * gamma, gamma_var

        def __call__(self, ref):
            raise AssertionError("run_headless calls predict() through the trust law")

    r = run_headless(robot, resolve_scenario("default_gap", robot), "trot_35", duration, 0, epsilon_fn=Perturbed(),
                     writer=None, ground_truth=False, progress=False)
    def per_5s(x, digits: int) -> list[float]:
        x = np.asarray(x)
        return [round(float(np.sqrt(np.mean(x[i:i + PER] ** 2))), digits) for i in range(0, len(x), PER)]

    print(json.dumps({"snapshot": os.path.basename(snap), "bad_from_s": t_bad, "bad_len_s": n_bad, "k": k,
                      "outside": outside,
                      "fell": bool(r.fell), "trust": r.epsilon_trust, "rms_per_5s": per_5s(r.feedback_effort, 1),
                      "attitude_error_rad_per_5s": per_5s(r.attitude_error, 4),
                      "joint_error_rad_per_5s": per_5s(r.joint_error, 4),
                      "base_position_error_m_per_5s": per_5s(r.base_position_error, 4)}))


if __name__ == "__main__":
    main()
