"""Headless runs: the plant, the inverse-dynamics controller and a reference in one
process, in lock-step with simulation time (no DDS), faster than real time.

`record` writes an MCAP bag with the live graph's topics and types; `closed_loop`
returns the paper's tracking metrics. Both use exactly the controller the
`id_controller` node runs.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ciml_control.controller import IdController
from ciml_control.references import make_reference
from ciml_learning import conversions as cv
from ciml_learning import topics
from ciml_learning.robot import RobotDescription

from .plant import Plant
from .scenario import Scenario

CONTROL_RATE = 250.0
"""Controller and sensor publishing rate [Hz]; physics and the joint PD run at 1 kHz."""
PHYSICS_STEPS_PER_TICK = 4


def measured_configuration(m) -> tuple[np.ndarray, np.ndarray]:
    """Pinocchio (q, v) from a plant measurement (base twist in the base frame)."""
    q = np.concatenate([m.base_position, m.base_orientation, m.q])
    v = np.concatenate([m.base_linear_velocity, m.base_angular_velocity, m.qd])
    return q, v


@dataclass
class RunResult:
    """What a headless run produced: time series of tracking and effort, and counters."""

    t: list[float] = field(default_factory=list)
    feedback_effort: list[float] = field(default_factory=list)      # ‖u_fb‖ [Nm]
    attitude_error: list[float] = field(default_factory=list)       # [rad]
    base_position_error: list[float] = field(default_factory=list)  # [m]
    joint_error: list[float] = field(default_factory=list)          # RMS over joints [rad]
    qp_failures: int = 0
    fell: bool = False
    fall_time: float | None = None

    def metrics(self) -> dict:
        def rms(x):
            return float(np.sqrt(np.mean(np.square(x)))) if x else float("nan")

        return {
            "rms_feedback_effort_nm": rms(self.feedback_effort),
            "rms_attitude_error_deg": float(np.degrees(rms(self.attitude_error))),
            "rms_base_position_error_mm": 1e3 * rms(self.base_position_error),
            "rms_joint_error_deg": float(np.degrees(rms(self.joint_error))),
            "qp_failures": self.qp_failures,
            "fell": self.fell,
            "fall_time_s": self.fall_time,
            "duration_s": self.t[-1] if self.t else 0.0,
            "samples": len(self.t),
        }


def run_headless(
    robot: RobotDescription,
    scenario: Scenario,
    motion: str,
    duration: float,
    seed: int,
    epsilon_fn: Callable[[object], np.ndarray] | None = None,
    writer=None,
    ground_truth: bool = True,
    progress: bool = True,
    min_base_height: float = 0.3,
) -> RunResult:
    """Run `motion` for `duration` s on the plant with the ID controller.

    epsilon_fn(reference_point) → ε (nv) is the model error used by the controller
    (None: the nominal model). With a `writer` (ciml_learning.bagio.BagWriter) every
    topic of the live graph is written; /sim/ ground truth only if `ground_truth`.
    The run stops early if the robot falls (base below `min_base_height` or
    non-finite state).
    """
    plant = Plant(robot, scenario, seed=seed)
    plant.reset()
    m0 = plant.measure()
    q_stand, _ = measured_configuration(m0)
    reference = make_reference(robot, motion, plant.standing_configuration())
    controller = IdController(robot)
    result = RunResult()
    n_ticks = int(round(duration * CONTROL_RATE))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_ticks, desc=f"{motion}", unit="tick", leave=False, mininterval=0.5)
    nv = robot.nv
    for k in range(n_ticks):
        m = plant.measure()
        ns = int(round(m.time * 1e9))
        q, v = measured_configuration(m)
        ref = reference.sample(m.time)
        eps = np.zeros(nv) if epsilon_fn is None else epsilon_fn(ref)
        out = controller.compute(q, v, m.contacts, ref, eps)
        if out.qp_failed:
            result.qp_failures += 1
        cmd = cv.TorqueCommandArrays(
            mode=0,
            feedforward=out.feedforward,
            feedback_linearization=out.feedback_linearization,
            position_target=out.q_target,
            velocity_target=out.qd_target,
            stiffness=out.kp,
            damping=out.kd,
        )
        if writer is not None:
            writer.write(topics.CLOCK, ns, _clock(ns))
            writer.write(topics.JOINT_STATES, ns, cv.joint_state_msg(robot, ns, m.q, m.qd, m.tau_measured))
            writer.write(topics.BASE_STATE, ns, cv.odometry_msg(ns, m.base_position, m.base_orientation,
                                                                m.base_linear_velocity, m.base_angular_velocity))
            writer.write(topics.CONTACT_STATE, ns, cv.contact_state_msg(robot, ns, m.contacts))
            writer.write(topics.TORQUE_COMMAND, ns, cv.torque_command_msg(robot, ns, cmd))
            if ground_truth:
                _write_ground_truth(writer, robot, ns, plant.ground_truth())
        # tracking metrics (paper Tables I–II): feedback = PD + linearisation part
        truth = plant.ground_truth()
        q_true = truth.q
        pd = out.kp * (out.q_target - m.q) + out.kd * (out.qd_target - m.qd)
        result.t.append(m.time)
        result.feedback_effort.append(float(np.linalg.norm(pd + out.feedback_linearization)))
        err = pin.difference(robot.model, ref.q, q_true)
        result.base_position_error.append(float(np.linalg.norm(err[:3])))
        result.attitude_error.append(float(np.linalg.norm(err[3:6])))
        result.joint_error.append(float(np.sqrt(np.mean(err[6:] ** 2))))
        if not np.all(np.isfinite(q_true)) or q_true[2] < min_base_height:
            result.fell, result.fall_time = True, m.time
            break
        plant.set_command(out.feedforward + out.feedback_linearization, out.q_target, out.qd_target, out.kp, out.kd)
        plant.step(PHYSICS_STEPS_PER_TICK)
        if bar is not None:
            bar.update()
    if bar is not None:
        bar.close()
    return result


def _clock(ns: int):
    from rosgraph_msgs.msg import Clock

    return Clock(clock=cv.stamp_msg(ns))


def _write_ground_truth(writer, robot: RobotDescription, ns: int, truth) -> None:
    from ciml_msgs.msg import ContactForces, GeneralizedForce

    header = cv.header_msg(ns)
    dof = list(robot.dof_names)
    writer.write(topics.SIM_ACCELERATION, ns, GeneralizedForce(header=header, label="acceleration", names=dof,
                                                                values=np.asarray(truth.vdot, float).tolist()))
    f = np.asarray(truth.contact_forces, float)
    writer.write(topics.SIM_CONTACT_FORCES, ns, ContactForces(header=header, foot_names=list(robot.foot_frames),
                                                               force_x=f[:, 0].tolist(), force_y=f[:, 1].tolist(),
                                                               force_z=f[:, 2].tolist()))
    for label, force in truth.effect_forces.items():
        writer.write(topics.SIM_EFFECT_PREFIX + label, ns,
                     GeneralizedForce(header=header, label=label, names=dof, values=np.asarray(force, float).tolist()))
