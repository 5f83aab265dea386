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

Speed: the reference is sampled on the exact 250 Hz grid t_k = k / 250 and the samples
are cached per (robot, motion, standing pose), so runs of the same motion (models,
scenarios, seeds) share them; messages go into the bag as CDR bytes from fixed-layout
templates (ciml_sim.serialized: rclpy's serialisation with the padding zeroed); the ground
truth is computed only when it is written; the metrics are computed from arrays at the
end of the run. Without Python between ticks (nominal model, no writer, no effect the
plant evaluates in Python) the ticks above run in one compiled call
(ciml_sim.joint_loop.closed_loop, the same functions as the step-by-step tick, which
takes the ticks it hands back).
"""
from __future__ import annotations

import array
import copy
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ciml_control.controller import IdController
from ciml_control.references import MOTIONS, make_reference
from ciml_control.trust import TrustedEpsilonFunction
from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription

from . import joint_loop
from .plant import GroundTruth, Measurement, Plant
from .scenario import Scenario

CONTROL_RATE = 250.0
"""Controller and sensor rate [Hz]; physics and the joint PD loop run at 1 kHz."""
PHYSICS_STEPS_PER_TICK = 4
SETTLE_TIME = 0.5
"""[s] unrecorded pre-roll holding the reference's first point, so that the soft contacts
and the actuators are loaded before t = 0."""
FALL_HEIGHT_FRACTION = 0.5
"""A base below this fraction of the robot's standing height counts as a fall (HyQ: 0.3 m of
~0.6 m); relative, so that a smaller robot (e.g. go1, ~0.33 m) is judged on its own size."""
FALL_TILT = np.radians(60.0)
SENSOR_RATES: tuple[float, ...] = (250.0, 500.0, 1000.0)
"""Rates [Hz] the sensor topics can be written at: the control rate or a divisor of the
1 kHz physics that splits a tick into whole physics steps."""


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

    t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    feedback_effort: np.ndarray = field(default_factory=lambda: np.zeros(0))      # ‖u_fb,pd + u_fb,lin‖ [Nm]
    attitude_error: np.ndarray = field(default_factory=lambda: np.zeros(0))       # angle of R_refᵀ R [rad]
    base_position_error: np.ndarray = field(default_factory=lambda: np.zeros(0))  # ‖p − p_ref‖ [m]
    joint_error: np.ndarray = field(default_factory=lambda: np.zeros(0))          # RMS over joints [rad]
    qp_failures: int = 0
    fell: bool = False
    fall_time: float | None = None
    controller: str = ""
    wall_time: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)          # wall seconds per stage
    python_ticks: int = 0   # control ticks run step by step in Python (the rest ran compiled)
    epsilon_trust: dict[str, int] = field(default_factory=dict)      # ticks with ε gated / clipped (trust law)

    def metrics(self) -> dict:
        """The paper's closed-loop metrics (Tables I–II) of this run."""

        def rms(x) -> float | None:
            return float(np.sqrt(np.mean(np.square(x)))) if len(x) else None

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


def make_controller(robot: RobotDescription, motion: str, q_stand: np.ndarray):
    """(controller, reference, name): the controller the `id_controller` node runs and the motion's reference."""
    return IdController(robot), make_reference(robot, motion, q_stand), "id_controller"


def check_motion(motion: str) -> None:
    """Raise a one-line CimlError naming the valid motions if `motion` is unknown."""
    if motion not in MOTIONS:
        raise RecordError(f"unknown motion {motion!r}; valid motions: {', '.join(MOTIONS)}")


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
    min_base_height: float | None = None,
    settle_time: float = SETTLE_TIME,
    sensor_rate: float = CONTROL_RATE,
) -> RunResult:
    """Run `motion` for `duration` seconds of simulation time on the plant with the controller.

    epsilon_fn(reference_point) → ε (nv), the model error eq. (17) the controller uses
    (None: the nominal model). With a `writer` (ciml_learning.logs.bagio.BagWriter) the live
    graph's topics are written (/joint_states, /base_state, /contact_state,
    /torque_command, /clock) and, if `ground_truth`, the /sim/ topics. The run stops
    early if the robot falls (base below `min_base_height` [m], default FALL_HEIGHT_FRACTION
    of the standing height, tilted over 60°, or a
    non-finite state); RunResult.fell says so.

    sensor_rate [Hz]: the rate of the written sensor topics (/joint_states, /base_state,
    /contact_state, /clock and the /sim/ ground truth), one of SENSOR_RATES; the controller
    still runs at CONTROL_RATE (one /torque_command per tick, applied by the 1 kHz joint loop
    in between), as a robot whose state estimator publishes faster than its controller.
    """
    if sensor_rate not in SENSOR_RATES:
        raise RecordError(f"sensor rate {sensor_rate} Hz is not supported; valid: "
                          f"{', '.join(f'{r:g}' for r in SENSOR_RATES)}")
    if not (np.isfinite(duration) and duration > 0):
        raise RecordError(f"duration must be a positive number of seconds, got {duration}")
    check_motion(motion)
    wall0 = time.perf_counter()
    plant = Plant(robot, scenario, seed=seed)
    q_stand = plant.standing_configuration()
    if min_base_height is None:
        min_base_height = FALL_HEIGHT_FRACTION * float(q_stand[2])
    controller, reference, name = make_controller(robot, motion, q_stand)
    grid = reference_grid(robot, motion, q_stand, reference)
    result = RunResult(controller=name)
    nv = robot.nv
    timing = {"plant_s": 0.0, "reference_s": 0.0, "controller_s": 0.0, "writer_s": 0.0, "compiled_s": 0.0}
    zeros = np.zeros(nv)  # ε of the nominal model (the controller only reads it)
    # the id_controller node's trust law (ciml_control.trust): gate ε by its variance, clip it to physics
    trusted = None if epsilon_fn is None else TrustedEpsilonFunction(robot, epsilon_fn)

    def eps(ref) -> np.ndarray:
        return zeros if trusted is None else trusted(ref)

    n_ticks = int(round(duration * CONTROL_RATE))
    sub_samples = int(round(sensor_rate / CONTROL_RATE))
    n_settle = int(round(settle_time * CONTROL_RATE))
    sample_writer = _SampleWriter(writer, robot, plant, ground_truth) if writer is not None else None
    # logs of the run (paper metrics from arrays at the end) and scratch logs of the pre-roll
    t_meas, effort = np.empty(n_ticks), np.empty(n_ticks)
    qpos = np.empty((n_ticks, plant.model.nq))   # true state (MuJoCo order: quaternion w x y z)
    q_ref = np.empty((n_ticks, robot.nq))
    settle_logs = (np.empty(n_settle), np.empty(n_settle), np.empty((n_settle, plant.model.nq)),
                   np.empty((n_settle, robot.nq)))
    qpos_now = plant.data.qpos
    cos_tilt = math.cos(FALL_TILT)
    # Without Python between ticks (nominal model, no bag, no effect evaluated in Python) the
    # ticks run in compiled code (joint_loop.closed_loop: the same functions as python_tick);
    # a tick it hands back (QP failure, a noise block to draw) runs in python_tick.
    compiled = epsilon_fn is None and sample_writer is None and plant.compiles_closed_loop
    if compiled:
        work, par = controller.workspace, controller.parameters
        gains = (np.ascontiguousarray(controller.gains.kp, dtype=float),
                 np.ascontiguousarray(controller.gains.kd, dtype=float))

    def python_tick(k: int, ref, logs, writer) -> bool:
        """One tick step by step; True if the robot fell (then no command is applied)."""
        result.python_ticks += 1
        t0 = time.perf_counter()
        m = plant.measure()
        t1 = time.perf_counter()
        e = eps(ref)
        t2 = time.perf_counter()
        q, v = measured_configuration(m)
        out = controller.compute(q, v, m.contacts, ref, e)
        t3 = time.perf_counter()
        if writer is not None:
            writer.write(m, out)
        t4 = time.perf_counter()
        # feedback effort from the command (PD part on the measured joints, as the joint loop
        # computes it); tracking errors of the true state
        pd = out.kp * (out.q_target - m.q)
        pd += out.kd * (out.qd_target - m.qd)
        pd += out.feedback_linearization
        logs[0][k], logs[1][k] = m.time, math.sqrt(pd @ pd)
        logs[2][k], logs[3][k] = qpos_now, ref.q
        if joint_loop.fallen(qpos_now, min_base_height, cos_tilt):
            return True
        plant.set_command(out.feedforward + out.feedback_linearization, out.q_target, out.qd_target, out.kp, out.kd,
                          stamp=m.time)  # computed for this sample (its /torque_command stamp)
        if writer is not None and sub_samples > 1:
            # sensor samples between two control ticks (no command: the controller runs at 250 Hz)
            for _ in range(sub_samples - 1):
                plant.step(PHYSICS_STEPS_PER_TICK // sub_samples)
                writer.write_sensors(plant.measure())
            plant.step(PHYSICS_STEPS_PER_TICK // sub_samples)
        else:
            plant.step(PHYSICS_STEPS_PER_TICK)
        t5 = time.perf_counter()
        timing["plant_s"] += (t1 - t0) + (t5 - t4)
        timing["reference_s"] += t2 - t1
        timing["controller_s"] += t3 - t2
        timing["writer_s"] += t4 - t3
        return False

    def run_ticks(count: int, point, refs, logs, writer, fall_height: float, bar) -> tuple[int, float | None]:
        """Ticks 0 … count−1 (reference point(k), or the rows of refs compiled): the ticks
        logged and the time of the fall (None if the robot did not fall)."""
        k = 0
        while k < count:
            if compiled:
                t0 = time.perf_counter()
                k_end, why, meas_i, stamp, has_rate = joint_loop.closed_loop(
                    plant.compiled_state(), work, par, *gains, joint_loop.ReferenceRows(*refs), k, count, plant.time,
                    PHYSICS_STEPS_PER_TICK, fall_height, cos_tilt, joint_loop.ClosedLoopLogs(*logs))
                fell = why == joint_loop.CLOSED_LOOP_FELL
                plant.compiled_done((k_end - k - fell) * PHYSICS_STEPS_PER_TICK, meas_i, stamp, has_rate)
                controller.steps += k_end - k
                timing["compiled_s"] += time.perf_counter() - t0
                if bar is not None:
                    bar.update(k_end - k)
                k = k_end
                if fell:
                    return k, float(logs[0][k - 1])
                if k >= count:
                    return k, None
            if python_tick(k, point(k), logs, writer):
                return k + 1, float(logs[0][k])
            if bar is not None:
                bar.update()
            k += 1
        return k, None

    # pre-roll: hold the first reference point (no height check: it only ends on a
    # non-finite or tipped-over state), then restart the clock at 0
    ref0 = grid.point(0)
    t0 = time.perf_counter()
    settle_refs = tuple(np.repeat(a[:1], n_settle, axis=0) for a in grid.arrays(1)) if compiled else None
    timing["reference_s"] += time.perf_counter() - t0
    run_ticks(n_settle, lambda k: ref0, settle_refs, settle_logs, None, -math.inf, None)
    plant.rewind_clock()
    qp_failures_before = controller.qp_failures

    t0 = time.perf_counter()
    refs = grid.arrays(n_ticks) if compiled else None
    timing["reference_s"] += time.perf_counter() - t0
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_ticks, desc=f"simulating {motion}", unit="tick", leave=False, mininterval=0.5)
    try:
        n, fall_time = run_ticks(n_ticks, grid.point, refs, (t_meas, effort, qpos, q_ref), sample_writer,
                                 min_base_height, bar)
    finally:
        if bar is not None:
            bar.close()
    result.fell, result.fall_time = fall_time is not None, fall_time
    result.qp_failures = controller.qp_failures - qp_failures_before
    if trusted is not None:
        result.epsilon_trust = dict(trusted.counts)
    _metrics_from_arrays(result, t_meas[:n], effort[:n], qpos[:n], q_ref[:n])
    result.wall_time = time.perf_counter() - wall0
    result.timings = {k: round(v, 4) for k, v in timing.items()}
    return result


def record_bag(robot: RobotDescription, scenario: Scenario, motion: str, duration: float, seed: int, out: str,
               ground_truth: bool = True, progress: bool = True,
               sensor_rate: float = CONTROL_RATE) -> tuple[RunResult, dict[str, int]]:
    """Run `motion` headless into a new bag `out` (zstd MCAP chunks: ~4× smaller, the joint and DoF
    names repeat in every message), the motion named in its metadata (bagio.MOTION_KEY) so that
    `ciml verify` can run it again; (the run, messages per topic)."""
    from ciml_learning.logs.bagio import MOTION_KEY, BagWriter

    writer = BagWriter(out, compression="zstd", custom_data={MOTION_KEY: motion})
    with writer:
        result = run_headless(robot, scenario, motion, duration, seed, writer=writer, ground_truth=ground_truth,
                              progress=progress, sensor_rate=sensor_rate)
    return result, dict(writer.counts)


def _metrics_from_arrays(result: RunResult, t: np.ndarray, effort: np.ndarray, qpos: np.ndarray,
                         q_ref: np.ndarray) -> None:
    """The tracking-error series of the true state (MuJoCo qpos rows) against the reference."""
    quat = qpos[:, [4, 5, 6, 3]]                                   # x y z w
    quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    quat_ref = q_ref[:, 3:7] / np.linalg.norm(q_ref[:, 3:7], axis=1, keepdims=True)
    # relative rotation R_refᵀ R as the quaternion conj(q_ref) ⊗ q: angle = 2 atan2(‖vec‖, |w|)
    xr, yr, zr, wr = (-quat_ref[:, 0], -quat_ref[:, 1], -quat_ref[:, 2], quat_ref[:, 3])
    x, y, z, w = quat.T
    rw = wr * w - xr * x - yr * y - zr * z
    rx = wr * x + xr * w + yr * z - zr * y
    ry = wr * y - xr * z + yr * w + zr * x
    rz = wr * z + xr * y - yr * x + zr * w
    result.t = t.copy()
    result.feedback_effort = effort.copy()
    result.attitude_error = 2.0 * np.arctan2(np.sqrt(rx * rx + ry * ry + rz * rz), np.abs(rw))
    result.base_position_error = np.linalg.norm(qpos[:, :3] - q_ref[:, :3], axis=1)
    result.joint_error = np.sqrt(np.mean((qpos[:, 7:] - q_ref[:, 7:]) ** 2, axis=1))


# --- the reference on the control grid, shared by runs ---------------------------------------------


class ReferenceGrid:
    """Reference points at t_k = k / CONTROL_RATE, sampled in order on first use and kept.

    The points are shared by every run of the same motion from the same standing pose;
    point(k) hands out a copy (a caller may modify it). Sampling in order reproduces
    what a run sampling tick by tick gets (the inverse kinematics warm-starts from the
    previous point).
    """

    def __init__(self, reference) -> None:
        self.reference = reference
        self.points: list = []
        self._lock = threading.Lock()
        self._arrays: tuple | None = None

    def arrays(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(q, v, a, contacts) of the points sampled so far, at least n, stacked in rows
        (kept; read-only)."""
        if self._arrays is None or len(self._arrays[0]) < n:
            self.point(n - 1)
            self._arrays = tuple(np.array([getattr(p, f) for p in self.points], dtype=d)
                                 for f, d in (("q", float), ("v", float), ("a", float), ("contacts", np.bool_)))
            for a in self._arrays:
                a.setflags(write=False)
        return self._arrays

    def point(self, k: int):
        if k >= len(self.points):
            with self._lock:
                while len(self.points) <= k:
                    self.points.append(self.reference.sample(len(self.points) / CONTROL_RATE))
        p = copy.copy(self.points[k])
        p.q, p.v, p.a, p.contacts = p.q.copy(), p.v.copy(), p.a.copy(), p.contacts.copy()
        return p


_GRIDS: OrderedDict[tuple, ReferenceGrid] = OrderedDict()
_GRIDS_LOCK = threading.Lock()
GRID_CACHE_SIZE = 6
"""Motions whose reference samples are kept in memory (~0.45 kB per 4 ms tick)."""


def reference_grid(robot: RobotDescription, motion: str, q_stand: np.ndarray, reference) -> ReferenceGrid:
    """The cached ReferenceGrid of (robot, motion, q_stand); `reference` starts a new one."""
    key = (type(reference).__module__, type(reference).__qualname__, str(robot.urdf_path), robot.joint_names,
           motion, np.asarray(q_stand, float).tobytes())
    with _GRIDS_LOCK:
        grid = _GRIDS.get(key)
        if grid is None:
            grid = _GRIDS[key] = ReferenceGrid(reference)
            while len(_GRIDS) > GRID_CACHE_SIZE:
                _GRIDS.popitem(last=False)
        else:
            _GRIDS.move_to_end(key)
        return grid


_SERIALIZERS: dict[tuple, object] = {}


def _sample_serializer(robot: RobotDescription):
    """The robot's SampleSerializer (built once per process, ~0.2 s), or None if a message
    has no fixed layout (then rclpy serialises every message)."""
    from .serialized import SampleSerializer, TemplateError

    key = (str(robot.urdf_path), robot.joint_names, tuple(robot.foot_frames), tuple(robot.dof_names))
    if key not in _SERIALIZERS:
        try:
            _SERIALIZERS[key] = SampleSerializer(robot)
        except TemplateError:  # pragma: no cover - every message here has a fixed layout
            _SERIALIZERS[key] = None
    return _SERIALIZERS[key]


class _SampleWriter:
    """Writes one tick's messages: CDR templates (ciml_sim.serialized) into a writer with
    `write_serialized` (BagWriter), else rclpy messages through `write`. The ground truth
    is computed here, only when it is written."""

    def __init__(self, writer, robot: RobotDescription, plant: Plant, ground_truth: bool) -> None:
        self.writer, self.robot, self.plant, self.ground_truth = writer, robot, plant, ground_truth
        self.serializer = _sample_serializer(robot) if hasattr(writer, "write_serialized") else None

    def write_sensors(self, m: Measurement) -> None:
        """The sensor topics (and the ground truth) of a sample between two control ticks."""
        truth = self.plant.ground_truth() if self.ground_truth else None
        ns = int(round(m.time * 1e9))
        if self.serializer is None:
            _write_sample(self.writer, self.robot, m, None, truth)
            return
        write, ser = self.writer.write_serialized, self.serializer
        write(topics.CLOCK, ns, ser.clock.serialize(ns))
        write(topics.JOINT_STATES, ns, ser.joint_states.serialize(ns, m.q, m.qd, m.tau_measured))
        write(topics.BASE_STATE, ns, ser.base_state.serialize(ns, m.base_position, m.base_orientation,
                                                             m.base_linear_velocity, m.base_angular_velocity))
        write(topics.CONTACT_STATE, ns, ser.contact_state.serialize(ns, m.contacts))
        if truth is not None:
            for topic, data in ser.ground_truth(ns, truth):
                write(topic, ns, data)

    def write(self, m: Measurement, out) -> None:
        truth = self.plant.ground_truth() if self.ground_truth else None
        ser = self.serializer
        if ser is None:
            _write_sample(self.writer, self.robot, m, out, truth)
            return
        ns = int(round(m.time * 1e9))
        write = self.writer.write_serialized
        for topic, data in ser.live(ns, m, out):
            write(topic, ns, data)
        if truth is not None:
            for topic, data in ser.ground_truth(ns, truth):
                write(topic, ns, data)


def _write_sample(writer, robot: RobotDescription, m: Measurement, out, truth: GroundTruth | None) -> None:
    """One sample's live topics (the command only with a controller output `out`) and ground truth."""
    from rosgraph_msgs.msg import Clock

    ns = int(round(m.time * 1e9))
    writer.write(topics.CLOCK, ns, Clock(clock=cv.stamp_msg(ns)))
    writer.write(topics.JOINT_STATES, ns, cv.joint_state_msg(robot, ns, m.q, m.qd, m.tau_measured))
    writer.write(topics.BASE_STATE, ns, cv.odometry_msg(ns, m.base_position, m.base_orientation,
                                                        m.base_linear_velocity, m.base_angular_velocity))
    writer.write(topics.CONTACT_STATE, ns, cv.contact_state_msg(robot, ns, m.contacts))
    if out is not None:
        cmd = cv.TorqueCommandArrays(mode=0, feedforward=np.asarray(out.feedforward, float),
                                     feedback_linearization=np.asarray(out.feedback_linearization, float),
                                     position_target=np.asarray(out.q_target, float),
                                     velocity_target=np.asarray(out.qd_target, float),
                                     stiffness=np.asarray(out.kp, float), damping=np.asarray(out.kd, float))
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
