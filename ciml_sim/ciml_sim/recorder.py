"""Headless runs: the plant, the inverse-dynamics controller and a reference in one
process, in lock-step with simulation time (no DDS), faster than real time.

Per 250 Hz tick at simulation time t (the live graph's order of events):
  1. the plant's sensors are read (Plant.measure: state at t; u and τ under the
     command in force before t),
  2. the controller computes a command from that sample and the reference at t,
  3. with a writer, the sample and the command are written stamped t (the live
     topics), and, with ground truth, the /sim/ topics at t,
  4. the command is sent and the plant runs 4 physics steps (the 1 kHz joint loop).

The same controller the `id_controller` node runs (ciml_control.controller.IdController
with ciml_control.references) drives every motion. Only if that package is missing,
a standing controller holds the `stand` motion.

Nothing written outside /sim/ depends on the scenario other than through the robot's
measured behaviour: no scenario name, file or effect is stored in the bag.
"""
from __future__ import annotations

import array
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import pinocchio as pin

from ciml_learning import conversions as cv
from ciml_learning import topics
from ciml_learning.errors import CimlError
from ciml_learning.robot import RobotDescription

from .mjcf import quat_xyzw_to_matrix
from .plant import GroundTruth, Measurement, Plant
from .scenario import Scenario

CONTROL_RATE = 250.0
"""Controller and sensor rate [Hz]; physics and the joint PD loop run at 1 kHz."""
PHYSICS_STEPS_PER_TICK = 4
SETTLE_TIME = 0.5
"""[s] unrecorded pre-roll holding the reference's first point, so that the soft contacts
and the actuators are loaded before t = 0."""
FALL_HEIGHT = 0.3
"""[m] a base below this height counts as a fall (HyQ stands at ~0.6 m)."""
FALL_TILT = np.radians(60.0)


class RecordError(CimlError):
    """A headless run cannot start (bad motion, duration or model)."""


def measured_configuration(m: Measurement) -> tuple[np.ndarray, np.ndarray]:
    """Pinocchio (q, v) from a plant measurement (base twist in the base frame)."""
    q = np.concatenate([m.base_position, m.base_orientation, m.q])
    v = np.concatenate([m.base_linear_velocity, m.base_angular_velocity, m.qd])
    return q, v


@dataclass
class RunResult:
    """Time series of tracking and effort of a headless run (true state vs reference), and counters."""

    t: list[float] = field(default_factory=list)
    feedback_effort: list[float] = field(default_factory=list)      # ‖u_fb,pd + u_fb,lin‖ [Nm]
    attitude_error: list[float] = field(default_factory=list)       # angle of R_refᵀ R [rad]
    base_position_error: list[float] = field(default_factory=list)  # ‖p − p_ref‖ [m]
    joint_error: list[float] = field(default_factory=list)          # RMS over joints [rad]
    qp_failures: int = 0
    fell: bool = False
    fall_time: float | None = None
    controller: str = ""
    wall_time: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)          # wall seconds per stage

    def metrics(self) -> dict:
        """The paper's closed-loop metrics (Tables I–II) of this run."""

        def rms(x: list[float]) -> float | None:
            return float(np.sqrt(np.mean(np.square(x)))) if x else None

        def scaled(x: float | None, s: float) -> float | None:
            return None if x is None else s * x

        duration = len(self.t) / CONTROL_RATE
        return {
            "rms_feedback_effort_nm": rms(self.feedback_effort),
            "rms_attitude_error_deg": scaled(rms(self.attitude_error), 180.0 / np.pi),
            "rms_base_position_error_mm": scaled(rms(self.base_position_error), 1e3),
            "rms_joint_error_deg": scaled(rms(self.joint_error), 180.0 / np.pi),
            "qp_failures": self.qp_failures,
            "fell": self.fell,
            "fall_time_s": self.fall_time,
            "duration_s": duration,
            "samples": len(self.t),
            "controller": self.controller,
            "real_time_factor": duration / self.wall_time if self.wall_time > 0 else None,
        }


# --- controller and reference --------------------------------------------------------------


@dataclass
class _Command:
    feedforward: np.ndarray
    feedback_linearization: np.ndarray
    q_target: np.ndarray
    qd_target: np.ndarray
    kp: np.ndarray
    kd: np.ndarray
    qp_failed: bool = False


class _StandReference:
    """Fallback reference (ciml_control.references missing): hold the standing pose."""

    period = 1.0

    def __init__(self, robot: RobotDescription, motion: str, q_stand: np.ndarray) -> None:
        if motion != "stand":
            raise RecordError(f"motion {motion!r} needs ciml_control.references, which is not installed; "
                              "only 'stand' is available")
        self.q, self.n_feet, self.nv = q_stand.copy(), robot.n_feet, robot.nv

    def sample(self, t: float):
        from types import SimpleNamespace

        return SimpleNamespace(t=t, q=self.q, v=np.zeros(self.nv), a=np.zeros(self.nv),
                               contacts=np.ones(self.n_feet, dtype=bool), phase=0.0, motion="stand")


class _StandingFallback:
    """Fallback controller (ciml_control.controller missing): ciml_control.standing."""

    def __init__(self, robot: RobotDescription) -> None:
        from ciml_control.standing import StandingController

        self.ctl = StandingController(robot)

    def compute(self, q, v, contacts, ref, epsilon=None) -> _Command:
        c = self.ctl.compute(ref.q, ref.contacts)
        return _Command(c.feedforward, c.feedback_linearization, c.q_target, c.qd_target, c.kp, c.kd)


def make_controller(robot: RobotDescription, motion: str, q_stand: np.ndarray):
    """(controller, reference, name): IdController and make_reference when ciml_control
    provides them (always, once installed), else the standing fallback."""
    try:
        from ciml_control.controller import IdController
        from ciml_control.references import make_reference
    except ImportError:
        return _StandingFallback(robot), _StandReference(robot, motion, q_stand), "standing_fallback"
    return IdController(robot), make_reference(robot, motion, q_stand), "id_controller"


def check_motion(motion: str) -> None:
    """Raise a one-line CimlError naming the valid motions if `motion` is unknown."""
    try:
        from ciml_control.references import MOTIONS
    except ImportError:
        MOTIONS = ("stand",)
    if motion not in MOTIONS:
        raise RecordError(f"unknown motion {motion!r}; valid motions: {', '.join(MOTIONS)}")


def default_duration(motion: str) -> float:
    try:
        from ciml_control.references import default_duration as dd
    except ImportError:
        return 20.0
    return float(dd(motion))


# --- the run -------------------------------------------------------------------------------------


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
    min_base_height: float = FALL_HEIGHT,
    settle_time: float = SETTLE_TIME,
) -> RunResult:
    """Run `motion` for `duration` seconds of simulation time on the plant with the controller.

    epsilon_fn(reference_point) → ε (nv), the model error eq. (17) the controller uses
    (None: the nominal model). With a `writer` (ciml_learning.bagio.BagWriter) the live
    graph's topics are written (/joint_states, /base_state, /contact_state,
    /torque_command, /clock) and, if `ground_truth`, the /sim/ topics. The run stops
    early if the robot falls (base below `min_base_height`, tilted over 60°, or a
    non-finite state); RunResult.fell says so.
    """
    if not (np.isfinite(duration) and duration > 0):
        raise RecordError(f"duration must be a positive number of seconds, got {duration}")
    check_motion(motion)
    wall0 = time.perf_counter()
    plant = Plant(robot, scenario, seed=seed)
    q_stand = plant.standing_configuration()
    controller, reference, name = make_controller(robot, motion, q_stand)
    result = RunResult(controller=name)
    nv = robot.nv
    timing = {"plant_s": 0.0, "reference_s": 0.0, "controller_s": 0.0, "writer_s": 0.0}

    def eps(ref) -> np.ndarray:
        return np.zeros(nv) if epsilon_fn is None else np.asarray(epsilon_fn(ref), dtype=float)

    # pre-roll: hold the first reference point, then restart the clock at 0
    ref0 = reference.sample(0.0)
    for _ in range(int(round(settle_time * CONTROL_RATE))):
        m = plant.measure()
        q, v = measured_configuration(m)
        out = controller.compute(q, v, m.contacts, ref0, eps(ref0))
        plant.set_command(out.feedforward + out.feedback_linearization, out.q_target, out.qd_target, out.kp, out.kd)
        plant.step(PHYSICS_STEPS_PER_TICK)
    plant.rewind_clock()

    n_ticks = int(round(duration * CONTROL_RATE))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_ticks, desc=f"simulating {motion}", unit="tick", leave=False, mininterval=0.5)
    try:
        for _ in range(n_ticks):
            t0 = time.perf_counter()
            m = plant.measure()
            truth = plant.ground_truth() if writer is not None and ground_truth else None
            q_true, _ = plant.true_state()
            t1 = time.perf_counter()
            ref = reference.sample(m.time)
            e = eps(ref)
            t2 = time.perf_counter()
            q, v = measured_configuration(m)
            out = controller.compute(q, v, m.contacts, ref, e)
            t3 = time.perf_counter()
            if writer is not None:
                _write_sample(writer, robot, m, out, truth)
            t4 = time.perf_counter()
            _track(result, m, out, ref, q_true)
            if not np.all(np.isfinite(q_true)) or q_true[2] < min_base_height or _tilt(q_true) > FALL_TILT:
                result.fell, result.fall_time = True, m.time
                break
            plant.set_command(out.feedforward + out.feedback_linearization, out.q_target, out.qd_target, out.kp, out.kd)
            plant.step(PHYSICS_STEPS_PER_TICK)
            t5 = time.perf_counter()
            timing["plant_s"] += (t1 - t0) + (t5 - t4)
            timing["reference_s"] += t2 - t1
            timing["controller_s"] += t3 - t2
            timing["writer_s"] += t4 - t3
            if bar is not None:
                bar.update()
    finally:
        if bar is not None:
            bar.close()
    result.wall_time = time.perf_counter() - wall0
    result.timings = {k: round(v, 4) for k, v in timing.items()}
    return result


def _tilt(q: np.ndarray) -> float:
    """Angle between the base's z axis and the world's [rad]."""
    x, y = q[3], q[4]
    return float(np.arccos(np.clip(1.0 - 2.0 * (x * x + y * y), -1.0, 1.0)))


def _track(result: RunResult, m: Measurement, out, ref, q_true: np.ndarray) -> None:
    """Paper metrics at one tick: feedback effort from the command (PD part on the measured
    joints, as the joint loop computes it); tracking errors of the true state."""
    pd = out.kp * (out.q_target - m.q) + out.kd * (out.qd_target - m.qd)
    result.t.append(m.time)
    result.feedback_effort.append(float(np.linalg.norm(pd + out.feedback_linearization)))
    result.base_position_error.append(float(np.linalg.norm(q_true[:3] - ref.q[:3])))
    R = quat_xyzw_to_matrix(q_true[3:7])
    R_ref = quat_xyzw_to_matrix(np.asarray(ref.q[3:7]) / np.linalg.norm(ref.q[3:7]))
    result.attitude_error.append(float(np.linalg.norm(pin.log3(R_ref.T @ R))))
    result.joint_error.append(float(np.sqrt(np.mean((q_true[7:] - ref.q[7:]) ** 2))))
    if getattr(out, "qp_failed", False):
        result.qp_failures += 1


def _write_sample(writer, robot: RobotDescription, m: Measurement, out, truth: GroundTruth | None) -> None:
    from rosgraph_msgs.msg import Clock

    ns = int(round(m.time * 1e9))
    cmd = cv.TorqueCommandArrays(mode=0, feedforward=np.asarray(out.feedforward, float),
                                 feedback_linearization=np.asarray(out.feedback_linearization, float),
                                 position_target=np.asarray(out.q_target, float),
                                 velocity_target=np.asarray(out.qd_target, float),
                                 stiffness=np.asarray(out.kp, float), damping=np.asarray(out.kd, float))
    writer.write(topics.CLOCK, ns, Clock(clock=cv.stamp_msg(ns)))
    writer.write(topics.JOINT_STATES, ns, cv.joint_state_msg(robot, ns, m.q, m.qd, m.tau_measured))
    writer.write(topics.BASE_STATE, ns, cv.odometry_msg(ns, m.base_position, m.base_orientation,
                                                        m.base_linear_velocity, m.base_angular_velocity))
    writer.write(topics.CONTACT_STATE, ns, cv.contact_state_msg(robot, ns, m.contacts))
    writer.write(topics.TORQUE_COMMAND, ns, cv.torque_command_msg(robot, ns, cmd))
    if truth is not None:
        write_ground_truth(writer, robot, ns, truth)


def _doubles(x) -> array.array:
    """float64[] field value without rclpy's per-element checks (array.array is taken as is)."""
    return array.array("d", np.ascontiguousarray(x, dtype=float).tobytes())


def ground_truth_messages(robot: RobotDescription, ns: int, truth: GroundTruth) -> list[tuple[str, object]]:
    """(topic, message) pairs of the /sim/ ground truth at one instant."""
    from ciml_msgs.msg import ContactForces, GeneralizedForce

    header = cv.header_msg(ns, "base")
    dof = list(robot.dof_names)
    f = np.asarray(truth.contact_forces, float)
    out: list[tuple[str, object]] = [
        (topics.SIM_ACCELERATION, GeneralizedForce(header=header, label="acceleration", names=dof,
                                                   values=_doubles(truth.vdot))),
        (topics.SIM_CONTACT_FORCES, ContactForces(header=cv.header_msg(ns, "world"), foot_names=list(robot.foot_frames),
                                                  force_x=_doubles(f[:, 0]), force_y=_doubles(f[:, 1]),
                                                  force_z=_doubles(f[:, 2]))),
    ]
    for label, force in truth.effect_forces.items():
        out.append((topics.SIM_EFFECT_PREFIX + label,
                    GeneralizedForce(header=header, label=label, names=dof, values=_doubles(force))))
    return out


def write_ground_truth(writer, robot: RobotDescription, ns: int, truth: GroundTruth) -> None:
    for topic, msg in ground_truth_messages(robot, ns, truth):
        writer.write(topic, ns, msg)


# --- benchmark (ciml bench) ------------------------------------------------------------------------


def speed_benchmark(motion: str = "trot_35", duration: float = 4.0, scenario: str = "default_gap") -> dict:
    """Headless real-time factor at 1 kHz physics with the controller (target ≥ 20×),
    without and with bag writing, and where the wall time goes."""
    import tempfile

    from ciml_learning.bagio import BagWriter
    from ciml_learning.robot import load_robot

    from .scenario import resolve_scenario

    robot = load_robot()
    scen = resolve_scenario(scenario, robot)
    out: dict = {"motion": motion, "scenario": scenario, "sim_duration_s": duration, "physics_rate_hz": 1000,
                 "target_real_time_factor": 20.0}
    r = run_headless(robot, scen, motion, duration, seed=0, progress=False)
    sim = len(r.t) / CONTROL_RATE
    loop_wall = sum(r.timings.values())
    out["real_time_factor"] = round(sim / r.wall_time, 2)
    out["real_time_factor_loop_only"] = round(sim / loop_wall, 2)
    out["wall_per_sim_second_s"] = {k: round(v / sim, 4) for k, v in r.timings.items()}
    out["controller"] = r.controller
    out["fell"] = r.fell
    with tempfile.TemporaryDirectory() as tmp:
        with BagWriter(f"{tmp}/bag") as w:
            r2 = run_headless(robot, scen, motion, duration, seed=0, writer=w, progress=False)
    out["real_time_factor_recording_with_ground_truth"] = round(len(r2.t) / CONTROL_RATE / r2.wall_time, 2)
    # the plant alone (physics + joint loop + sensors), holding a standing command
    plant = Plant(robot, scen, seed=0)
    nj = robot.n_joints
    q0 = plant.standing_configuration()
    plant.set_command(np.zeros(nj), q0[7:], np.zeros(nj), np.full(nj, 300.0), np.full(nj, 8.0))
    t0 = time.perf_counter()
    n = 1000
    for _ in range(n):
        plant.measure()
        plant.step(PHYSICS_STEPS_PER_TICK)
    wall = time.perf_counter() - t0
    out["plant_only_real_time_factor"] = round(n * PHYSICS_STEPS_PER_TICK * 1e-3 / wall, 2)
    out["plant_us_per_physics_step"] = round(wall / (n * PHYSICS_STEPS_PER_TICK) * 1e6, 2)
    return out
