"""The trot's lean orbits (results/LIVE_GRAPH.md, eighteenth session): the headless closed loop
(ciml_sim.recorder.run_headless, deterministic, no ROS) on default_gap trot_35 with a fixed model
under the controller's trust law, its ε × K for 5 s from KICK_AT (K = 1: no kick), and the base
orientation gain KP [1/s²] (damping ratio kept: KD = 25 √(KP/200)). Prints per 5 s the RMS feedback
effort, the mean attitude error as a rotation vector (roll, pitch, yaw) [deg] and the mean base
position error (x, y, z) [mm]: which lean the robot trots at, and whether a kick moves it.
usage: lean.py MODEL DURATION KICK_AT K KP (MODEL: nominal, a model directory or a diagnosis directory)"""
import json
import math
import sys

import numpy as np
import pinocchio as pin

import ciml_sim.recorder as recorder
from ciml_control.controller import IdController
from ciml_control.feedback import BASE_LINEAR_KD, BASE_LINEAR_KP, FeedbackGains
from ciml_control.references import make_reference
from ciml_learning.core.profile import load_profile
from ciml_sim.commands import load_epsilon_function
from ciml_sim.scenario import resolve_scenario

PER = 250 * 5  # control steps per 5 s


def main() -> None:
    model, (duration, kick_at, k, kp) = sys.argv[1], (float(a) for a in sys.argv[2:6])
    robot = load_profile("hyq").robot()
    gains = FeedbackGains.default(robot, base_kp=(BASE_LINEAR_KP, kp),
                                  base_kd=(BASE_LINEAR_KD, 25.0 * math.sqrt(kp / 200.0)))
    recorder.make_controller = lambda r, motion, q_stand: (IdController(r, gains=gains),
                                                           make_reference(r, motion, q_stand), "id_controller")
    fn = load_epsilon_function(robot, model)
    inner = fn if fn is not None else (lambda ref: np.zeros(robot.nv))
    start: list[float] = []

    def kicked(x, t: float):
        if not start:
            start.append(t)
        return k * x if kick_at <= t - start[0] < kick_at + 5.0 else x

    class Kicked:
        """The model's prediction (with variances, so that the trust law's gate applies) × K in the kick."""

        model_set = getattr(fn, "model_set", None)

        def predict(self, ref):
            out = fn.predict(ref)
            if out is None:
                return out
            rbd, rbd_var, gamma, gamma_var = out
            return kicked(rbd, float(ref.t)), rbd_var, kicked(gamma, float(ref.t)), gamma_var

        def __call__(self, ref):
            return kicked(np.asarray(inner(ref)), float(ref.t))

    logs: dict[str, np.ndarray] = {}
    metrics = recorder._metrics_from_arrays

    def keep(result, t, effort, qpos, q_ref):
        logs.update(qpos=qpos.copy(), q_ref=q_ref.copy())
        metrics(result, t, effort, qpos, q_ref)

    recorder._metrics_from_arrays = keep
    eps = Kicked() if hasattr(fn, "model_set") else Kicked().__call__
    r = recorder.run_headless(robot, resolve_scenario("default_gap", robot), "trot_35", duration, 0, epsilon_fn=eps,
                              writer=None, ground_truth=False, progress=False)
    qpos, q_ref = logs["qpos"], logs["q_ref"]

    def rotation(i: int) -> np.ndarray:
        w, x, y, z = qpos[i, 3:7]
        xr, yr, zr, wr = q_ref[i, 3:7]
        R = pin.Quaternion(w, x, y, z).normalized().toRotationMatrix()
        R_ref = pin.Quaternion(wr, xr, yr, zr).normalized().toRotationMatrix()
        return pin.log3(R_ref.T @ R)

    rows = []
    for s in range(0, len(qpos), PER):
        e = slice(s, s + PER)
        attitude = np.mean([rotation(i) for i in range(s, min(s + PER, len(qpos)), 5)], axis=0)
        rows.append({"t_s": s / 250, "effort_nm": round(float(np.sqrt(np.mean(r.feedback_effort[e] ** 2))), 1),
                     "attitude_deg": np.round(np.degrees(attitude), 2).tolist(),
                     "position_mm": np.round(1e3 * np.mean(qpos[e, :3] - q_ref[e, :3], axis=0), 1).tolist()})
    print(json.dumps({"model": model, "kick_at_s": kick_at, "k": k, "base_angular_kp": kp, "fell": bool(r.fell),
                      "per_5s": rows}))


if __name__ == "__main__":
    main()
