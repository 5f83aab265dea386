"""Does an LWPR model set learned online get worse in closed loop as it keeps learning the same trot?

    python drift.py BAG MINUTES,... [BUFFER]   # BAG: go1_gap trot_35 recorded with the nominal controller

The bag's samples (`ciml train`'s extraction, CIML-topics profile) are learned in time order with
partial_fit, as the online learner does (default scaling: calibration_samples 0; Γ also from every
4th state near a contact change: the extractor's effort_sample_every); after each given minute of
the log, the model so far drives a closed loop (trot_35 30 s, seed 11; RMS feedback effort [Nm]).
BUFFER > 0: the samples go through a streaming shuffle first (each new one takes a random slot of a
BUFFER-sample buffer and the one it displaces is learned; each sample is learned once, in an order
decorrelated over about BUFFER samples). Then each group of the last model (base, leg, actuation)
in the first one, in closed loop; and, along a nominal closed loop's references, each model's calf
rigid-body error against the true calf friction there (go1_gap: 0.8 Nm Coulomb, smoothed over
0.03 rad/s, + 0.3 N m s/rad viscous).
"""
import copy
import sys

import numpy as np
from go1_log import effort, learning_order, load, robot, scenario

from ciml_learning.core.extraction import learning_inputs
from ciml_learning.core.physical_bounds import N_BASE
from ciml_learning.learning.models import ModelSet
from ciml_sim.recorder import run_headless

tg, effort_rows = load(sys.argv[1])
buffer = int(sys.argv[3]) if len(sys.argv) > 3 else 0
order = learning_order(np.flatnonzero(effort_rows), buffer)
print("nominal", effort(None), flush=True)
ms = ModelSet.for_robot(robot, "lwpr")
t = tg.t - tg.t[0]
start = 0
snapshots = []
for minute in (float(m) for m in sys.argv[2].split(",")):
    end = int(np.searchsorted(t[order], 60.0 * minute)) if buffer <= 0 else int(np.sum(t[order] < 60.0 * minute))
    part = order[start:end]
    ms.partial_fit(tg.inputs[part], tg.generalized_error[part], tg.generalized_observed[part],
                   tg.actuation_error[part], tg.valid[part], tg.leg_coupling[part], effort_valid=effort_rows[part])
    start = end
    snapshots.append(copy.deepcopy(ms))
    fields = {g: sum(ms.models_[i].n_receptive_fields for i in ms.group_dims(g) if ms.models_[i] is not None)
              for g in ("base", "leg", "actuation")} if ms.is_fitted() else {}
    print(f"after {minute:g} min ({int(ms.n_samples_.max())} samples most per dimension) {fields}: "
          f"effort {effort(ms)}", flush=True)

first, last = snapshots[0], snapshots[-1]
for group in ("base", "leg", "actuation"):
    mixed = copy.deepcopy(first)
    for i in mixed.group_dims(group):
        mixed.models_[i] = copy.deepcopy(last.models_[i])
    print(f"first model with the last one's {group}: effort {effort(mixed)}", flush=True)
references = []


def nominal(ref):
    references.append((np.array(ref.q), np.array(ref.v), np.array(ref.a)))
    return np.zeros(robot.nv)


run_headless(robot, scenario, "trot_35", 30.0, 11, epsilon_fn=nominal, progress=False)
Q, V, A = (np.array(z) for z in zip(*references))
X = learning_inputs(Q, V, A, np.zeros((len(Q), robot.n_joints)), np.zeros((len(Q), robot.n_joints)))
for minute, model in zip(sys.argv[2].split(","), snapshots):
    e = model.predict(X, return_var=False).rbd
    row = []
    for j, joint in enumerate(robot.joint_names):
        if "calf" in joint:
            truth = 0.8 * np.tanh(V[:, 6 + j] / 0.03) + 0.3 * V[:, 6 + j]
            learned = e[:, N_BASE + j]
            corr, rms = np.corrcoef(learned, truth)[0, 1], np.sqrt(np.mean(learned ** 2))
            row.append(f"{joint[:2]} corr {corr:.2f} rms {rms:.2f} (truth {np.sqrt(np.mean(truth ** 2)):.2f})")
    print(f"after {minute} min, calves at the references: " + " | ".join(row))
