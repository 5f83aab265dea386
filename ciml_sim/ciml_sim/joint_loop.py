"""The plant's 1 kHz joint loop, compiled (numba), stepping MuJoCo through its C API.

At 1 kHz a Python loop around `mujoco.mj_step` spends more time in a dozen small numpy
operations per step than MuJoCo spends on the physics. `run_joint_loop` runs n steps of
the joint loop (encoder reading, PD law, clipping, actuator lag, gain and offset; see
ciml_sim.plant) and MuJoCo's `mj_step` in one compiled call: MuJoCo's C functions are
called by address (`mj_function`) on the very mjModel/mjData the Python bindings hold,
so the bindings see every step. `actuation` is the same law for one reading; the plant
uses it wherever it needs u and τ (one law, one place).

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
import os
from functools import lru_cache

import mujoco
import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.extending import intrinsic


@lru_cache(maxsize=None)
def mj_function(name: str) -> int:
    """Address of MuJoCo's C function `name` (void f(const mjModel*, mjData*)) in the
    libmujoco the Python bindings loaded (dlopen of the same file returns the same library)."""
    libs = sorted(glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*")))
    if not libs:  # pragma: no cover - every mujoco wheel for Linux ships it
        raise ImportError(f"libmujoco not found next to {mujoco.__file__}")
    lib = ctypes.CDLL(libs[-1])
    return int(ctypes.cast(getattr(lib, name), ctypes.c_void_p).value)


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


@njit(cache=True)
def actuation(q: np.ndarray, qd: np.ndarray, encoder_offset: np.ndarray, noise_q: np.ndarray,
              noise_qd: np.ndarray, t: float, c: np.ndarray, c_rate: np.ndarray, has_rate: bool, stamp: float,
              kp: np.ndarray, kd: np.ndarray, limits: np.ndarray, has_lag: bool, alpha: np.ndarray,
              lag: np.ndarray, has_gain: bool, gain: np.ndarray, offset: np.ndarray, q_m: np.ndarray,
              qd_m: np.ndarray, u: np.ndarray, lag_out: np.ndarray, tau: np.ndarray) -> None:
    """The joint loop at one reading (ciml_sim.plant's docstring), into q_m, qd_m, u, lag_out, τ:

        q_m = q + offset (+ noise),  q̇_m = q̇ (+ noise)
        u = clip(c − K_p q_m − K_d q̇_m + ċ (t − t_c), ±limits),   c = u_ff + K_p q_t + K_d q̇_t
        lag_out = lag + α (u − lag)   (backward-Euler first-order lag; u without lag)
        τ = g · lag_out + o           (lag_out without gain/offset)

    noise_q, noise_qd: this reading's encoder noise, or empty arrays for none.
    """
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
def run_joint_loop(mj_step: int, mj_step2: int, model: int, data: int, n: int, reuse_first: bool, t: float,
                   dt: float, q: np.ndarray, qd: np.ndarray, ctrl: np.ndarray, encoder_offset: np.ndarray,
                   noise_q: np.ndarray, noise_qd: np.ndarray, c: np.ndarray, c_rate: np.ndarray, has_rate: bool,
                   stamp: float, kp: np.ndarray, kd: np.ndarray, limits: np.ndarray, has_lag: bool,
                   alpha: np.ndarray, lag: np.ndarray, has_gain: bool, gain: np.ndarray, offset: np.ndarray,
                   u: np.ndarray, tau: np.ndarray) -> None:
    """n physics steps: the joint loop's τ into ctrl, then MuJoCo's step (mj_step2 for the
    first if `reuse_first`: mj_forward's position and velocity stages are already in
    mjData). q, qd, ctrl: views of mjData's joint qpos, qvel and ctrl; t: mjData's time
    (advanced by dt per step as MuJoCo does); noise_q, noise_qd: n rows of encoder noise
    or empty (0 × n_j) for none; lag is updated in place, u and τ hold the last step's."""
    nj = q.shape[0]
    q_m = np.empty(nj)
    qd_m = np.empty(nj)
    lag_new = np.empty(nj)
    no_noise = np.empty(0)
    noisy = noise_q.shape[0] > 0
    for i in range(n):
        nq = noise_q[i] if noisy else no_noise
        nqd = noise_qd[i] if noisy else no_noise
        actuation(q, qd, encoder_offset, nq, nqd, t, c, c_rate, has_rate, stamp, kp, kd, limits,
                  has_lag, alpha, lag, has_gain, gain, offset, q_m, qd_m, u, lag_new, tau)
        lag[:] = lag_new
        ctrl[:] = tau
        _call_model_data(mj_step2 if (i == 0 and reuse_first) else mj_step, model, data)
        t += dt
