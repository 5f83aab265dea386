"""Does the long-learned model's loss come from inputs at the references beyond its data?

    python clip_inputs.py BAG MINUTES   # as drift.py (1,000-sample shuffle), one model after MINUTES

The model set learned online from MINUTES of BAG drives the closed loop (trot_35 30 s, seed 11) with
the references' joint inputs q, q̇, q̈ given to the models as they are, and clipped per column to the
1st–99th percentile of the learned rows (what the swing data support); RMS feedback effort [Nm].
"""
import sys

import numpy as np
from go1_log import effort, learning_order, load, robot

from ciml_learning.core.extraction import learning_inputs
from ciml_learning.learning.model_epsilon import EpsilonFunction
from ciml_learning.learning.models import ModelSet

tg, rows = load(sys.argv[1])
order = learning_order(np.flatnonzero(rows), 1000)  # drift.py's streaming shuffle
order = order[(tg.t[order] - tg.t[0]) < 60.0 * float(sys.argv[2])]
ms = ModelSet.for_robot(robot, "lwpr")
ms.partial_fit(tg.inputs[order], tg.generalized_error[order], tg.generalized_observed[order],
               tg.actuation_error[order], tg.valid[order], tg.leg_coupling[order], effort_valid=rows[order])
swing = tg.valid[order]
joints = [i for i, n in enumerate(ms.input_names) if n.startswith(("q_", "qd_", "qdd_"))]
lo, hi = (np.percentile(tg.inputs[order][swing][:, joints], p, axis=0) for p in (1, 99))


class Clipped(EpsilonFunction):
    def predict(self, ref, reference_torque=None, foot_jacobians=None):
        x = learning_inputs(np.asarray(ref.q, float), np.asarray(ref.v, float), np.asarray(ref.a, float),
                            np.zeros(robot.n_joints), np.zeros(robot.n_joints))[0]
        x[joints] = np.clip(x[joints], lo, hi)
        out = super().predict(ref, reference_torque, foot_jacobians)
        if out is None:
            return None
        rbd, rbd_var = self.model_set.predict_part_one(x, "rbd")
        return (rbd, rbd_var, *out[2:])


outside = []
probe = EpsilonFunction(robot, ms)


def as_is(ref):
    x = learning_inputs(np.asarray(ref.q, float), np.asarray(ref.v, float), np.asarray(ref.a, float),
                        np.zeros(robot.n_joints), np.zeros(robot.n_joints))[0][joints]
    outside.append((x < lo) | (x > hi))
    return probe(ref)


print(f"after {sys.argv[2]} min of the log: as is {effort(as_is)}", flush=True)
share = np.mean(outside, axis=0)
print("share of references outside the 1–99 % range, per input: "
      + ", ".join(f"{ms.input_names[c]} {s:.2f}" for c, s in zip(joints, share) if "calf" in ms.input_names[c]))
print(f"clipped to the learned rows' range: {effort(Clipped(robot, ms))}", flush=True)
