"""Does Γ's rate input at the reference, τ̇_ref, lose by being a backward difference?

    python rate_lead.py ROBOT SCENARIO BAG MINUTES MODE...

A model set learned from the first MINUTES of BAG as the live learner learns it (order.py's rows,
held-back blocks, time order) drives the closed loop (trot_35 30 s, seed 11; RMS feedback effort
[Nm]) with τ̇_ref from dynamics.ReferenceTorque computed per MODE:
backward (today: (τ_ref(t) − τ_ref(t − Δ))/Δ), central ((τ_ref(t + Δ) − τ_ref(t − Δ))/2Δ) or
forward ((τ_ref(t + Δ) − τ_ref(t))/Δ), τ_ref(t + Δ) from the reference sampled one control period
ahead (a reference published ahead lets a server do this); or extrapolated: the forward
difference from the past alone, the slope at t + Δ/2 of the parabola through τ_ref at t − 2Δ,
t − Δ, t: (2τ(t) − 3τ(t − Δ) + τ(t − 2Δ))/Δ. Within one contact schedule only.
The modes were run at e914e98, whose ReferenceTorque gave the backward difference; since then
ReferenceTorque itself extrapolates, so `backward` here is the extrapolated rate (the check
line in rate_lead_output.txt).
"""
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from live_log import effort, learn, load  # noqa: E402

import ciml_sim.recorder as recorder  # noqa: E402
from ciml_learning.core.dynamics import ReferenceTorque  # noqa: E402
from ciml_learning.learning.model_epsilon import EpsilonFunction  # noqa: E402
from ciml_learning.learning.models import ModelSet  # noqa: E402

name, scenario_name, bag, minutes = sys.argv[1:5]
modes = sys.argv[5:]
robot, scenario, tg, t, rows = load(name, scenario_name, bag)
ms = ModelSet.for_robot(robot, "lwpr")
learn(ms, tg, rows, np.flatnonzero(rows & (t < 60.0 * float(minutes))))
DT = 1.0 / recorder.CONTROL_RATE
current = {}
make_reference = recorder.make_reference


def capture(*args):
    current["reference"] = make_reference(*args)
    return current["reference"]


recorder.make_reference = capture


class LeadTorque(ReferenceTorque):
    def __init__(self, robot, mode):
        super().__init__(robot)
        self.mode = mode

    def __call__(self, ref, e=None, foot_jacobians=None):
        tau, tau_dot = super().__call__(ref, e, foot_jacobians)
        if self.mode == "backward":
            return tau, tau_dot
        if self.mode == "extrapolated":
            previous, self.previous = getattr(self, "previous", None), tau_dot
            if not np.any(tau_dot) or previous is None or not np.any(previous):
                return tau, tau_dot
            return tau, 2.0 * tau_dot - previous  # (2τ0 − 3τ1 + τ2)/Δ with equal steps
        ahead = current["reference"].sample(float(ref.t) + DT)
        contacts = np.asarray(getattr(ref, "contacts", np.ones(robot.n_feet, bool)), bool)
        if not np.array_equal(np.asarray(ahead.contacts, bool), contacts):
            return tau, tau_dot
        tau_ahead = self.torque(np.asarray(ahead.q, float), np.asarray(ahead.v, float), np.asarray(ahead.a, float),
                                contacts, e)
        forward = (tau_ahead - tau) / DT
        if self.mode == "forward" or not np.any(tau_dot):
            return tau, forward
        return tau, 0.5 * (forward + tau_dot)


for mode in modes:
    fn = EpsilonFunction(robot, ms)
    fn.reference_torque = LeadTorque(robot, mode)
    print(f"{name} model of {minutes} min, τ̇_ref {mode}: effort {effort(robot, scenario, fn):.3f}", flush=True)
