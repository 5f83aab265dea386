"""Which part of a learned model limits the closed loop (a study, not product).

Runs `ciml closed-loop`'s loop (recorder.run_headless, seed 1001, default gap) with ε built
from a learned model set where one part is replaced by the scenario's true effects
(results/true_effects, the default gap written as a diagnosis model):

    rbd_true    true rigid-body error, learned Γ          act_true   learned Φ̃, true Γ
    base_true   true base wrench, learned legs and Γ      legs_true  learned base, true legs
    zero_phase  all learned; τ̇_ref from the training filter (filters.derivative_taps)
                applied zero-phase over the reference ahead (needs the reference's future:
                possible headless, not in the live graph)

    python results/experiment_studies/limits_study.py VARIANT MODEL_DIR [MOTION,MOTION,...]

Prints RMS ‖u_fb‖ [Nm] per motion (results/EXPERIMENT.md, "What is left").
"""
from __future__ import annotations

import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "tools"))
from experiment import NEW_MOTIONS, ROOT, SCENARIO, TRAIN_MOTIONS  # noqa: E402  (tools/experiment.py)

from ciml_control.references import default_duration
from ciml_learning.core.dynamics import ReferenceTorque, selection_matrix
from ciml_learning.core.extraction import combined_error
from ciml_learning.core.filters import delay_samples, derivative_taps
from ciml_learning.core.physical_bounds import N_BASE
from ciml_learning.core.robot import load_robot
from ciml_learning.diagnosis import load_effect_model
from ciml_learning.learning.model_epsilon import EpsilonFunction
from ciml_learning.learning.models import ModelSet
from ciml_sim.plant import Plant
from ciml_sim.recorder import CONTROL_RATE, make_reference, run_headless
from ciml_sim.scenario import resolve_scenario

VARIANTS = ("rbd_true", "act_true", "base_true", "legs_true", "zero_phase")
MOTIONS = ",".join(TRAIN_MOTIONS + NEW_MOTIONS)


def epsilon_function(variant: str, robot, model_set: ModelSet, truth, reference):
    learned = EpsilonFunction(robot, model_set)
    if variant == "zero_phase":
        return _zero_phase(learned, reference)
    S = selection_matrix(robot)
    truth_torque = ReferenceTorque(robot)  # its own τ̇ state (learned.predict advances the other)

    def eps(ref) -> np.ndarray:
        prediction = learned.predict(ref)
        assert prediction is not None  # None only for a non-finite reference point
        rbd, _, gamma, _ = prediction
        if variant == "act_true":
            gamma = truth.actuation_error(*truth_torque(ref, rbd))
        else:
            true_rbd = truth.rbd_force(*(np.asarray(x, float) for x in (ref.q, ref.v, ref.a)))
            keep = {"rbd_true": slice(0, 0), "base_true": slice(N_BASE, None), "legs_true": slice(0, N_BASE)}[variant]
            true_rbd[keep] = rbd[keep]  # the learned part that stays
            rbd = true_rbd
        return combined_error(None, rbd, gamma, S)

    return eps


class _ZeroPhaseTorque(ReferenceTorque):
    """τ_ref as ReferenceTorque gives it; τ̇_ref = the training derivative filter over the nominal
    τ_ref of the reference ticks k − d … k + d (filters.filter_offline's convention, newest first)."""

    def __init__(self, robot, reference) -> None:
        super().__init__(robot)
        self.reference = reference
        self.taps, self.d = derivative_taps(CONTROL_RATE), delay_samples()
        self._nominal: dict[int, np.ndarray] = {}

    def _torque_at(self, k: int) -> np.ndarray:
        if k not in self._nominal:
            p = self.reference.sample(max(k, 0) / CONTROL_RATE)
            self._nominal[k] = self.torque(p.q, p.v, p.a, np.asarray(p.contacts, bool))
        return self._nominal[k]

    def __call__(self, ref, e: np.ndarray | None = None,
                 foot_jacobians: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        tau, _ = super().__call__(ref, e, foot_jacobians)
        k = int(round(ref.t * CONTROL_RATE))
        return tau, self.taps @ np.array([self._torque_at(k + j) for j in range(self.d, -self.d - 1, -1)])


def _zero_phase(learned: EpsilonFunction, reference) -> EpsilonFunction:
    """`learned` with τ̇_ref from the reference ahead (_ZeroPhaseTorque)."""
    learned.reference_torque = _ZeroPhaseTorque(learned.robot, reference)
    return learned


def main() -> int:
    variant, model_dir = sys.argv[1], sys.argv[2]
    if variant not in VARIANTS:
        raise SystemExit(f"unknown variant {variant!r}; valid: {', '.join(VARIANTS)}")
    motions = (sys.argv[3] if len(sys.argv) > 3 else MOTIONS).split(",")
    robot = load_robot()
    model_set = ModelSet.load(model_dir, robot)
    truth = load_effect_model(robot, os.path.join(ROOT, "results", "true_effects"))
    scenario = resolve_scenario(SCENARIO, robot)
    q_stand = Plant(robot, scenario, seed=0).standing_configuration()
    out = {}
    for motion in motions:
        eps = epsilon_function(variant, robot, model_set, truth, make_reference(robot, motion, q_stand))
        r = run_headless(robot, scenario, motion, default_duration(motion), 1001, epsilon_fn=eps, progress=False)
        out[motion] = round(r.metrics()["rms_feedback_effort_nm"], 2)
        print(variant, motion, out[motion], flush=True)
    print(json.dumps({variant: out}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
