"""The plant's 1 kHz joint loop, compiled (numba), stepping MuJoCo through its C API.

At 1 kHz a Python loop around `mujoco.mj_step` spends more time in a dozen small numpy
operations per step than MuJoCo spends on the physics. `run_joint_loop` runs n steps of
the joint loop (encoder reading, PD law, clipping, actuator lag, gain and offset; see
ciml_sim.plant) and MuJoCo's `mj_step` in one compiled call: MuJoCo's C functions are
called by address (`mj_function`) on the very mjModel/mjData the Python bindings hold,
so the bindings see every step. `actuation` is the same law for one reading; the plant
uses it wherever it needs u and τ (one law, one place).

The commanded torque u is a compiled copy of ciml_learning.core.conversions.commanded_torque,
the law's specification (what the learning side computes Γ = τ − u with), written in
coefficient form (`command_coefficients`, then `actuation`) so that the 1 kHz loop does
four multiply-adds per joint; test_joint_loop_law asserts the two agree on random inputs.
test_effects checks the compiled loop against the plant's documented law written out
step by step in Python, and measure()'s u and τ against those the next step applies.
A MuJoCo fatal error inside the compiled loop (none is expected: the model's memory is
sized at load) would end the process rather than raise; warnings are unaffected.

Compiled on first use and cached on disk (numba `cache=True`): the MuJoCo function
addresses are arguments, never compiled-in constants, so the cache stays valid from
one process to the next.
"""
from __future__ import annotations

import ctypes
import glob
import math
import os
from functools import lru_cache
from typing import NamedTuple

import mujoco
import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic

from ciml_control.compiled.control_step import (
    ControlInput,
    ControlOutputBuffers,
    ControlParameters,
    ControlWorkspace,
    control_step,
)
from ciml_control.compiled.linalg import all_finite


@lru_cache(maxsize=None)
def mj_function(name: str) -> int:
    """Address of MuJoCo's C function `name` (void f(const mjModel*, mjData*)) in the
    libmujoco the Python bindings loaded (dlopen of the same file returns the same library)."""
    libs = sorted(glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*")))
    if not libs:  # pragma: no cover - every mujoco wheel for Linux ships it
        raise ImportError(f"libmujoco not found next to {mujoco.__file__}")
    lib = ctypes.CDLL(libs[-1])
    ptr = ctypes.cast(getattr(lib, name), ctypes.c_void_p).value
    assert ptr is not None  # a resolved symbol is never NULL
    return ptr


@intrinsic
def _call_model_data(typingctx, fn, m, d):
    """fn(m, d) for the address fn of a C function void f(const mjModel*, mjData*)."""
    sig = types.void(types.intp, types.intp, types.intp)

    def codegen(context, builder, signature, args):
        ptr = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [ptr, ptr])
        f = builder.inttoptr(args[0], fnty.as_pointer())
        builder.call(f, [builder.inttoptr(args[1], ptr), builder.inttoptr(args[2], ptr)])
        return context.get_dummy_value()

    return sig, codegen


class MujocoCalls(NamedTuple):
    """MuJoCo's C functions by address (mj_function) and the mjModel*, mjData* of the Python
    bindings they act on."""

    mj_step: int
    mj_step2: int
    mj_forward: int
    mj_rne_post_constraint: int
    model: int
    data: int


class Actuators(NamedTuple):
    """The joint loop's torque limits and the scenario's actuator effects (ciml_sim.plant):
    what `actuation` applies after the law. Arrays per joint; `lag` is the lag's state."""

    encoder_offset: np.ndarray  # added to the true joint positions [rad]
    limits: np.ndarray          # torque limits of the joint loop [Nm]
    has_lag: bool               # first-order lag: α per joint and the lag state (updated by run_joint_loop)
    alpha: np.ndarray
    lag: np.ndarray
    has_gain: bool              # τ = gain · lag + offset
    gain: np.ndarray
    offset: np.ndarray


class HeldCommand(NamedTuple):
    """The TorqueCommand the joint loop holds, as its coefficients (command_coefficients):
    u = c − K_p q_m − K_d q̇_m + ċ (t − stamp)."""

    c: np.ndarray               # u_ff + K_p q_t + K_d q̇_t
    c_rate: np.ndarray          # ċ = K_p q̇_t
    kp: np.ndarray
    kd: np.ndarray
    has_rate: bool              # any ċ ≠ 0
    stamp: float                # the command's stamp [s of simulation time]


class JointReading(NamedTuple):
    """What `actuation` writes: the joint loop at one reading (arrays per joint)."""

    q_m: np.ndarray             # measured joint positions and velocities (offset and noise included)
    qd_m: np.ndarray
    u: np.ndarray               # commanded torque (the law, clipped)
    lag: np.ndarray             # the lag state after this reading
    tau: np.ndarray             # the torque the actuators deliver


class Sensors(NamedTuple):
    """What `sense` reads besides the state: MjData views, the feet and the sensor effects."""

    xmat_base: np.ndarray       # the base body's rotation (MjData.xmat row, 9)
    cfrc_ext: np.ndarray        # MjData.cfrc_ext
    foot_bodies: np.ndarray     # body ids of the feet (int)
    imu_tilt: np.ndarray        # IMU mounting tilt (w, x, y, z; empty for none)
    noise_std: np.ndarray       # sensor noise: orientation, torque, position, twist
    contact_threshold: float    # normal force of a contact [N]
    sensor: np.ndarray          # torque-sensor gain, offset, ripple amplitude and period per joint (0 rows: ideal)


class SensorReading(NamedTuple):
    """What `sense` writes: one sample of the robot's sensors."""

    quat_xyzw: np.ndarray       # base orientation
    pos: np.ndarray             # base position (world) [m]
    lin: np.ndarray             # base twist in the base frame [m/s, rad/s]
    ang: np.ndarray
    tau_meas: np.ndarray        # joint torque sensors [Nm]
    forces: np.ndarray          # contact force of each foot (world frame) [N]
    contacts: np.ndarray        # contact flag of each foot (bool)


@njit(cache=True)
def actuation(q: np.ndarray, qd: np.ndarray, act: Actuators, cmd: HeldCommand, noise_q: np.ndarray,
              noise_qd: np.ndarray, t: float, out: JointReading) -> None:
    """The joint loop at one reading (ciml_sim.plant's docstring) under the held command `cmd`,
    into `out`:

        q_m = q + offset (+ noise),  q̇_m = q̇ (+ noise)
        u = clip(c − K_p q_m − K_d q̇_m + ċ (t − t_c), ±limits),   c = u_ff + K_p q_t + K_d q̇_t

    u is a compiled copy of ciml_learning.core.conversions.commanded_torque (the specification;
    test_joint_loop_law asserts they agree on random inputs); the lag, gain and offset are
    the scenario's actuator effects (`act`, the "reality" after the law):
        out.lag = act.lag + α (u − act.lag)   (backward-Euler first-order lag; u without lag)
        τ = g · out.lag + o                   (out.lag without gain/offset)

    noise_q, noise_qd: this reading's encoder noise, or empty arrays for none.
    """
    encoder_offset, limits, has_lag, alpha, lag, has_gain, gain, offset = act  # the records' fields, in order
    c, c_rate, kp, kd, has_rate, stamp = cmd
    q_m, qd_m, u, lag_out, tau = out
    noisy = noise_q.shape[0] > 0
    for j in range(q.shape[0]):
        qm = q[j] + encoder_offset[j]
        qdm = qd[j]
        if noisy:
            qm = qm + noise_q[j]
            qdm = qdm + noise_qd[j]
        uj = c[j] - kp[j] * qm
        uj -= kd[j] * qdm
        if has_rate:
            uj += c_rate[j] * (t - stamp)
        uj = min(uj, limits[j])
        uj = max(uj, -limits[j])
        lj = lag[j] + alpha[j] * (uj - lag[j]) if has_lag else uj
        q_m[j], qd_m[j], u[j], lag_out[j] = qm, qdm, uj, lj
        tau[j] = gain[j] * lj + offset[j] if has_gain else lj


@njit(cache=True)
def run_joint_loop(mj: MujocoCalls, n: int, reuse_first: bool, t: float, dt: float, q: np.ndarray,
                   qd: np.ndarray, ctrl: np.ndarray, act: Actuators, cmd: HeldCommand, noise_q: np.ndarray,
                   noise_qd: np.ndarray, u: np.ndarray, tau: np.ndarray) -> None:
    """n physics steps: the joint loop's τ into ctrl, then MuJoCo's step (mj_step2 for the
    first if `reuse_first`: mj_forward's position and velocity stages are already in
    mjData). q, qd, ctrl: views of mjData's joint qpos, qvel and ctrl; t: mjData's time
    (advanced by dt per step as MuJoCo does); noise_q, noise_qd: n rows of encoder noise
    or empty (0 × n_j) for none; act.lag is updated in place, u and τ hold the last step's."""
    nj = q.shape[0]
    reading = JointReading(np.empty(nj), np.empty(nj), u, np.empty(nj), tau)
    no_noise = np.empty(0)
    noisy = noise_q.shape[0] > 0
    for i in range(n):
        nq = noise_q[i] if noisy else no_noise
        nqd = noise_qd[i] if noisy else no_noise
        actuation(q, qd, act, cmd, nq, nqd, t, reading)
        act.lag[:] = reading.lag
        ctrl[:] = tau
        _call_model_data(mj.mj_step2 if (i == 0 and reuse_first) else mj.mj_step, mj.model, mj.data)
        t += dt


@njit(cache=True)
def command_coefficients(u_ff: np.ndarray, q_target: np.ndarray, qd_target: np.ndarray, kp: np.ndarray,
                         kd: np.ndarray, damping_mode: bool, c: np.ndarray, c_rate: np.ndarray,
                         kp_out: np.ndarray, kd_out: np.ndarray) -> int:
    """A TorqueCommand as the joint loop's coefficients (see `actuation`; with it, a compiled
    copy of ciml_learning.core.conversions.commanded_torque, tested equal to it):
    c = u_ff + K_p q_t + K_d q̇_t, ċ = K_p q̇_t, K_p, K_d; in damping mode c = ċ = K_p = 0.
    Returns 0, or 1 for a non-finite value, 2 for a negative gain (nothing written)."""
    n = u_ff.shape[0]
    for j in range(n):
        if not (np.isfinite(u_ff[j]) and np.isfinite(q_target[j]) and np.isfinite(qd_target[j])
                and np.isfinite(kp[j]) and np.isfinite(kd[j])):
            return 1
        if kp[j] < 0 or kd[j] < 0:
            return 2
    for j in range(n):
        if damping_mode:
            c[j], c_rate[j], kp_out[j] = 0.0, 0.0, 0.0
        else:
            c[j] = u_ff[j] + kp[j] * q_target[j] + kd[j] * qd_target[j]
            c_rate[j] = kp[j] * qd_target[j]
            kp_out[j] = kp[j]
        kd_out[j] = kd[j]
    return 0


@njit(cache=True)
def _mul_quat(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a ⊗ b (w, x, y, z), as mju_mulQuat."""
    return np.array([a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
                     a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
                     a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
                     a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]])


@njit(cache=True)
def _quat_integrate(quat: np.ndarray, rotation: np.ndarray) -> np.ndarray:
    """quat ⊗ exp(rotation / 2) (rotation vector in the rotated frame), as mju_quatIntegrate
    with scale 1."""
    angle = math.sqrt(rotation[0] * rotation[0] + rotation[1] * rotation[1] + rotation[2] * rotation[2])
    if angle == 0.0:
        return quat.copy()
    s = math.sin(0.5 * angle) / angle
    return _mul_quat(quat, np.array([math.cos(0.5 * angle), rotation[0] * s, rotation[1] * s, rotation[2] * s]))


@njit(cache=True)
def sense(mj: MujocoCalls, qpos: np.ndarray, qvel: np.ndarray, sensors: Sensors, z: np.ndarray, tau: np.ndarray,
          out: SensorReading) -> None:
    """MuJoCo's forward pass at the current state under the applied torque, then the
    sensors of ciml_sim.plant.Plant.measure into `out`: base orientation
    (IMU tilt imu_tilt (w, x, y, z; empty for none), orientation noise), position, base-frame
    twist and torque with their noise (noise_std: orientation, torque, position, twist;
    z: this sample's standard-normal draws of the enabled ones, in that order), each foot's
    contact force (world frame) and contact flag (normal force above contact_threshold).
    The torque sensor of joint j reads sensor[j, 0]·τ_j + sensor[j, 1] + sensor[j, 2]·sin(2π q_j / sensor[j, 3])
    (+ noise): its gain, offset and a position-dependent ripple (q_j the true joint position); an
    empty `sensor` (0 rows) reads τ_j.
    A foot's contact force is the external force on its body (cfrc_ext after
    mj_rnePostConstraint, linear part): its sphere is the body's only colliding geom (mjcf.py)."""
    xmat_base, cfrc_ext, foot_bodies, imu_tilt, noise_std, contact_threshold, sensor = sensors  # fields, in order
    quat_xyzw, pos, lin, ang, tau_meas, forces, contacts = out
    _call_model_data(mj.mj_forward, mj.model, mj.data)
    _call_model_data(mj.mj_rne_post_constraint, mj.model, mj.data)  # cfrc_ext: the contact forces on the bodies
    for i in range(foot_bodies.shape[0]):
        for a in range(3):
            forces[i, a] = cfrc_ext[foot_bodies[i], 3 + a]
        contacts[i] = forces[i, 2] > contact_threshold
    for a in range(3):  # base frame: Rᵀ v (xmat row-major), as mju_mulMatTVec3
        lin[a] = xmat_base[a] * qvel[0] + xmat_base[3 + a] * qvel[1] + xmat_base[6 + a] * qvel[2]
        ang[a] = qvel[3 + a]
        pos[a] = qpos[a]
    quat = qpos[3:7].copy()  # w x y z
    if imu_tilt.shape[0] == 4:
        quat = _mul_quat(quat, imu_tilt)
    o = 0
    if noise_std[0] > 0:  # rotation vector in the base frame
        quat = _quat_integrate(quat, noise_std[0] * z[0:3])
        o = 3
    norm = math.sqrt(quat[0] * quat[0] + quat[1] * quat[1] + quat[2] * quat[2] + quat[3] * quat[3])
    for a in range(4):
        quat_xyzw[a] = quat[(a + 1) % 4] / norm
    nj = tau.shape[0]
    for j in range(nj):
        tau_meas[j] = tau[j]
    if sensor.shape[0] == nj:
        for j in range(nj):
            tau_meas[j] = sensor[j, 0] * tau[j] + sensor[j, 1]
            if sensor[j, 2] != 0.0:
                tau_meas[j] += sensor[j, 2] * math.sin(2.0 * math.pi * qpos[7 + j] / sensor[j, 3])
    if noise_std[1] > 0:
        for j in range(nj):
            tau_meas[j] += noise_std[1] * z[o + j]
        o += nj
    if noise_std[2] > 0:
        for a in range(3):
            pos[a] += noise_std[2] * z[o + a]
        o += 3
    if noise_std[3] > 0:
        for a in range(3):
            lin[a] += noise_std[3] * z[o + a]
            ang[a] += noise_std[3] * z[o + 3 + a]


CLOSED_LOOP_DONE = 0
CLOSED_LOOP_FELL = 1
CLOSED_LOOP_HANDBACK = 2
"""Why `closed_loop` returned: all ticks run, the robot fell (the last tick's sample is
logged, no command applied), or a tick it leaves to the caller (not started: a QP
failure, a non-finite state, reference or torque, a noise block to refill)."""


@njit(cache=True)
def fallen(qpos: np.ndarray, min_base_height: float, cos_tilt: float) -> bool:
    """Non-finite state, base below min_base_height, or tilted beyond the angle of cos_tilt
    (MuJoCo qpos: quaternion w, x, y, z)."""
    s = 0.0
    for x in qpos:
        s += x * x
    if not math.isfinite(s):  # a non-finite (or exploded) state
        return True
    w, x, y, z = qpos[3], qpos[4], qpos[5], qpos[6]
    n2 = w * w + x * x + y * y + z * z
    # base z axis · world z = 1 − 2 (x² + y²) for the normalised quaternion
    return qpos[2] < min_base_height or 1.0 - 2.0 * (x * x + y * y) / n2 < cos_tilt


class PlantState(NamedTuple):
    """The plant as `closed_loop` reads and updates it (Plant.compiled_state(); arrays shared
    with the Plant and its MjData and updated in place; the scalars come back through
    ClosedLoopResult and Plant.compiled_done). Units SI, joint order of the robot."""

    mujoco: MujocoCalls
    qpos: np.ndarray          # MjData.qpos (quaternion w, x, y, z), qvel
    qvel: np.ndarray
    qj: np.ndarray            # the joints' views of qpos, qvel, ctrl
    vj: np.ndarray
    ctrl: np.ndarray
    actuators: Actuators      # (its lag state updated)
    command: HeldCommand      # the held command (its arrays updated; stamp and rate flag come back)
    sensors: Sensors
    noisy: bool               # encoder noise drawn (enc_q, enc_qd hold a block)
    enc_q: np.ndarray         # encoder noise block (physics steps × n_j), row enc_i next
    enc_qd: np.ndarray
    enc_i: int
    meas_noise: np.ndarray    # sensor noise draws (samples × draws per sample; 0 columns: none), row meas_i next
    meas_i: int
    u: np.ndarray             # the last physics step's commanded torque u and actuator torque τ (out)
    tau: np.ndarray
    dt: float                 # physics step [s]


class ReferenceRows(NamedTuple):
    """The reference on the control grid: row k is tick k (recorder.ReferenceGrid.arrays)."""

    q: np.ndarray             # qᵈ (ticks × nq)
    v: np.ndarray             # q̇ᵈ (ticks × nv)
    a: np.ndarray             # q̈ᵈ (ticks × nv)
    contacts: np.ndarray      # contact schedule (ticks × n_feet, bool)


class ClosedLoopLogs(NamedTuple):
    """Per-tick logs of the paper metrics written by closed_loop (row k: tick k)."""

    t: np.ndarray             # sample time [s]
    effort: np.ndarray        # ‖u_fb‖ = ‖PD part + u_fb,lin‖ [Nm]
    qpos: np.ndarray          # true MuJoCo qpos
    q_ref: np.ndarray         # qᵈ


class ClosedLoopResult(NamedTuple):
    """Where closed_loop stopped and the plant scalars it advanced (Plant.compiled_done)."""

    k: int                    # the first tick not run
    why: int                  # CLOSED_LOOP_DONE, _FELL or _HANDBACK
    meas_i: int               # sensor-noise row after the last tick run
    stamp: float              # the last command's stamp and rate flag
    has_rate: bool


@njit(cache=True)
def closed_loop(plant: PlantState, work: ControlWorkspace, par: ControlParameters, kp: np.ndarray, kd: np.ndarray,
                refs: ReferenceRows, k0: int, k1: int, t: float, steps_per_tick: int, min_base_height: float,
                cos_tilt: float, logs: ClosedLoopLogs) -> ClosedLoopResult:
    """Ticks k0 … k1−1 of the headless closed loop (ciml_sim.recorder.run_headless) without
    leaving compiled code: at each tick the plant's sample (`actuation` and `sense`, as
    Plant.measure), the controller's step (ciml_control.compiled.control_step, nominal
    model), the logs of the paper metrics, the command (`command_coefficients`, as
    Plant.set_command) and `steps_per_tick` physics steps (`run_joint_loop`, as Plant.step).
    The same functions, in the same order, as the step-by-step path; `plant` is
    Plant.compiled_state(), `work` and `par` IdController.workspace and .parameters, kp
    and kd the joint PD gains of the commands, refs the reference on the control grid.

    Returns where it stopped, why (CLOSED_LOOP_*), and the plant's scalars it advanced: the
    measurement-noise block position after the last tick run, the last command's stamp and
    rate flag (Plant.compiled_done takes them back)."""
    p = plant
    qpos, qj, vj, ctrl = p.qpos, p.qj, p.vj, p.ctrl
    noisy, enc_q, enc_qd, enc_i, meas_noise, meas_i = p.noisy, p.enc_q, p.enc_qd, p.enc_i, p.meas_noise, p.meas_i
    held = p.command  # its arrays updated in place; a new record at each command (stamp, rate flag)
    ref_q, ref_v, ref_a, ref_contacts = refs.q, refs.v, refs.a, refs.contacts
    t_log, effort_log, qpos_log, q_ref_log = logs.t, logs.effort, logs.qpos, logs.q_ref
    nj = qj.shape[0]
    nf = p.sensors.foot_bodies.shape[0]
    nv = nj + 6
    no_noise = np.empty(0)
    q_m, qd_m, u_now, lag_now, tau_now = np.empty(nj), np.empty(nj), np.empty(nj), np.empty(nj), np.empty(nj)
    quat, pos, lin, ang, tau_meas = np.empty(4), np.empty(3), np.empty(3), np.empty(3), np.empty(nj)
    forces, contacts = np.empty((nf, 3)), np.empty(nf, dtype=np.bool_)
    reading = JointReading(q_m, qd_m, u_now, lag_now, tau_now)
    sample = SensorReading(quat, pos, lin, ang, tau_meas, forces, contacts)
    q, v, eps = np.empty(nj + 7), np.empty(nv), np.zeros(nv)
    u_ff, u_lin, planned = np.empty(nj), np.empty(nj), np.empty((nf, 3))
    total = np.empty(nj)
    for k in range(k0, k1):
        if (noisy and enc_i + steps_per_tick > enc_q.shape[0]) or (meas_noise.shape[1] > 0
                                                                    and meas_i >= meas_noise.shape[0]):
            return ClosedLoopResult(k, CLOSED_LOOP_HANDBACK, meas_i, held.stamp, held.has_rate)
        # the sample (Plant.measure)
        actuation(qj, vj, p.actuators, held, enc_q[enc_i] if noisy else no_noise,
                  enc_qd[enc_i] if noisy else no_noise, t, reading)
        ctrl[:] = tau_now
        sense(p.mujoco, qpos, p.qvel, p.sensors, meas_noise[meas_i] if meas_noise.shape[1] > 0 else no_noise,
              tau_now, sample)
        q[:3] = pos  # the measured configuration (recorder.measured_configuration)
        q[3:7] = quat
        q[7:] = q_m
        v[:3] = lin
        v[3:6] = ang
        v[6:] = qd_m
        # the controller (IdController.compute, nominal model)
        step = control_step(work, par, ControlInput(q, v, contacts, ref_q[k], ref_v[k], ref_a[k], ref_contacts[k], eps),
                            ControlOutputBuffers(u_ff, u_lin, planned))
        if step.flags != 0 or step.status != 0 or not (all_finite(u_ff) and all_finite(u_lin)):
            return ClosedLoopResult(k, CLOSED_LOOP_HANDBACK, meas_i, held.stamp, held.has_rate)
        # the tick is committed from here: noise consumed, logs written
        if meas_noise.shape[1] > 0:
            meas_i += 1
        s = 0.0
        for j in range(nj):  # feedback effort: the PD part as the joint loop computes it, plus u_fb,lin
            pd = kp[j] * (ref_q[k, 7 + j] - q_m[j]) + kd[j] * (ref_v[k, 6 + j] - qd_m[j]) + u_lin[j]
            s += pd * pd
            total[j] = u_ff[j] + u_lin[j]
        effort_log[k] = math.sqrt(s)
        t_log[k] = t
        qpos_log[k] = qpos
        q_ref_log[k] = ref_q[k]
        if fallen(qpos, min_base_height, cos_tilt):
            return ClosedLoopResult(k + 1, CLOSED_LOOP_FELL, meas_i, held.stamp, held.has_rate)
        # the command (Plant.set_command, stamped with the sample's time) and the physics (Plant.step)
        command_coefficients(total, ref_q[k, 7:], ref_v[k, 6:], kp, kd, False, held.c, held.c_rate, held.kp,
                             held.kd)
        has_rate = False
        for j in range(nj):
            if held.c_rate[j] != 0.0:
                has_rate = True
        held = HeldCommand(held.c, held.c_rate, held.kp, held.kd, has_rate, t)
        run_joint_loop(p.mujoco, steps_per_tick, True, t, p.dt, qj, vj, ctrl, p.actuators, held,
                       enc_q[enc_i:enc_i + steps_per_tick] if noisy else enc_q,
                       enc_qd[enc_i:enc_i + steps_per_tick] if noisy else enc_qd, p.u, p.tau)
        for _ in range(steps_per_tick):
            t += p.dt
        if noisy:
            enc_i += steps_per_tick
    return ClosedLoopResult(k1, CLOSED_LOOP_DONE, meas_i, held.stamp, held.has_rate)
