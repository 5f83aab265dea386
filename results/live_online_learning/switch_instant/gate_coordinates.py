"""Where the trust gate compares variances. The headless closed loop (go1_gap, trot_35, 40 s,
seed 42) with a fixed model and the trust law applied three ways:
  generalized  Φ̃ (the model set's output) with its variance: the headless loop's law;
  prime        Φ̃' = J'⁻ᵀΦ̃ with the variance and the prior mapped by (J'⁻ᵀ)∘², as the model server
               published and the live controller gated before the fix;
  none         no gate.
Prints the steps with a gated entry, per entry, and the RMS feedback effort over the last 30 s.

    python gate_coordinates.py MODE SNAPSHOT ...   → output.txt
"""
import sys

import numpy as np

import ciml_sim.recorder as recorder
from ciml_control import trust
from ciml_learning.core.dynamics import RigidBodyDynamics
from ciml_learning.core.profile import load_profile, profile_path
from ciml_learning.core.projection import contact_invariant_basis
from ciml_learning.learning.model_epsilon import EpsilonFunction
from ciml_learning.learning.models import ModelSet
from ciml_sim.scenario import resolve_scenario

mode, snapshots = sys.argv[1], sys.argv[2:]
robot = load_profile(profile_path("go1")).robot()
dynamics = RigidBodyDynamics(robot)


class Gate(trust.TrustedEpsilonFunction):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.per_entry = np.zeros(len(robot.rbd_error_names) + robot.n_joints, int)

    def __call__(self, ref) -> np.ndarray:
        rbd, rbd_var, gamma, gamma_var = self._predict(ref)
        if mode == "prime":
            basis = contact_invariant_basis(dynamics.foot_jacobians(np.asarray(ref.q, float)), robot.leg_joints)
            inverse_t = np.linalg.inv(basis.T)
            out = self.law.apply(inverse_t @ rbd, inverse_t ** 2 @ rbd_var, gamma, gamma_var, basis)
        else:
            out = self.law.apply(rbd, None if mode == "none" else rbd_var, gamma, None if mode == "none" else gamma_var)
        self.per_entry[:len(out.gated)] += out.gated
        self.counts["epsilon_gated"] += bool(out.gated.any())
        return out.epsilon


for snapshot in snapshots:
    gates: list[Gate] = []
    recorder.TrustedEpsilonFunction = lambda *a, **k: gates.append(Gate(*a, **k)) or gates[-1]
    fn = EpsilonFunction(robot, ModelSet.load(snapshot, robot))
    run = recorder.run_headless(robot, resolve_scenario("go1_gap", robot), "trot_35", 40.0, 42, epsilon_fn=fn,
                                progress=False)
    e = np.asarray(run.feedback_effort)
    gated = {i: int(n) for i, n in enumerate(gates[0].per_entry) if n}
    print(snapshot.rstrip("/").split("/")[-1], mode, "steps gated", gates[0].counts["epsilon_gated"],
          "per entry", gated, f"RMS effort 10-40 s {np.sqrt(np.mean(e[len(e) // 4:] ** 2)):.3f} Nm", flush=True)
