"""Pinocchio over batches of samples: the offline path's per-sample dynamics in one call per batch.

Extraction (M q̈ + h and the foot Jacobians of every sample) and the diagnosis's regressors (the
joint torque regressor, ∂RNEA/∂q, ∂J/∂q) called Pinocchio from Python several times per sample;
each call's wrapper cost more than its algorithm (HyQ: ~10 µs of Python per sample for
extraction's dynamics). The C++ side (ciml_learning/cpp/batch_core.cpp, compiled by
tools/install.sh against the pin wheel's headers) runs the very same Pinocchio algorithms over a
whole batch; the model is passed as Pinocchio's own archive, so it is the robot's model, whatever
was loaded. Each call builds its own pinocchio::Data and ctypes releases the GIL, so threads may
share a robot's BatchDynamics. The same library holds the contact-invariant projection's per-sample
linear algebra (bound here, called by core.projection and core.extraction).
"""
from __future__ import annotations

import ctypes
import os
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from ciml_learning.core.errors import CimlError

if TYPE_CHECKING:
    from ciml_learning.core.robot import RobotDescription

LIBRARY = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "libciml_learning_core.so")

_P = ctypes.c_void_p
_I = ctypes.c_int64


class BatchCoreError(CimlError):
    """The batch core is missing or refused its input."""


@lru_cache(maxsize=None)
def library() -> ctypes.CDLL:
    if not os.path.isfile(LIBRARY):
        raise BatchCoreError(f"the batch dynamics core {LIBRARY} is not built; run tools/install.sh")
    lib = ctypes.CDLL(LIBRARY)
    lib.ciml_batch_new.restype = _P
    lib.ciml_batch_new.argtypes = [ctypes.c_char_p, _P, _I]
    lib.ciml_batch_free.argtypes = [_P]
    lib.ciml_batch_inverse_dynamics.restype = _I
    lib.ciml_batch_inverse_dynamics.argtypes = [_P, _I, _P, _P, _P, _P, _P]
    lib.ciml_batch_regressors.restype = _I
    lib.ciml_batch_regressors.argtypes = [_P, _I, _P, _P, _P, _P, _P, _P]
    lib.ciml_batch_jacobian_variation_products.restype = _I
    lib.ciml_batch_jacobian_variation_products.argtypes = [_P, _I, _P, _P, _P, _P, _I, _P, _P]
    lib.ciml_contact_invariant_bases.restype = _I
    lib.ciml_contact_invariant_bases.argtypes = [_I, _I, _I, _P, _P, ctypes.c_double, _P]
    lib.ciml_observe.restype = _I
    lib.ciml_observe.argtypes = [_I, _I, _I, _P, _P, _P, _P, _P, _P]
    lib.ciml_leg_coupling.restype = _I
    lib.ciml_leg_coupling.argtypes = [_I, _I, _I, _P, _P, _P]
    return lib


def _rows(x: np.ndarray, width: int, what: str) -> np.ndarray:
    x = np.ascontiguousarray(x, dtype=float)
    if x.ndim != 2 or x.shape[1] != width:
        raise BatchCoreError(f"{what} must be N × {width}, got {x.shape}")
    return x


def address(x: np.ndarray) -> int:
    """The data pointer of a C-contiguous array, for the core's functions."""
    return x.ctypes.data


def check(status: int, what: str) -> None:
    """Raise BatchCoreError on a core function's non-zero status."""
    if status != 0:
        raise BatchCoreError(f"the batch dynamics core failed in {what} (status {status})")


class BatchDynamics:
    """A robot's model and feet in the batch core (RobotDescription.batch builds it once)."""

    def __init__(self, robot: RobotDescription) -> None:
        lib = library()
        feet = np.array(robot.foot_frame_ids, dtype=np.int64)
        handle = lib.ciml_batch_new(robot.model.saveToString().encode(), address(feet), feet.size)
        if not handle:
            raise BatchCoreError("the batch dynamics core could not load the robot model")
        self.handle = int(handle)
        self._free = lib.ciml_batch_free
        self.nq, self.nv, self.n_feet = robot.model.nq, robot.model.nv, feet.size
        self.n_inertial = 10 * (robot.model.njoints - 1)

    def __del__(self) -> None:
        if getattr(self, "handle", 0):
            self._free(self.handle)
            self.handle = 0

    def inverse_dynamics(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per sample: RNEA(q, v, a) = M q̈ + h (N × nv) and the feet's linear Jacobians
        (N × n_feet × 3 × nv, LOCAL_WORLD_ALIGNED)."""
        q, v, a = _rows(q, self.nq, "q"), _rows(v, self.nv, "v"), _rows(a, self.nv, "a")
        n = len(q)
        if len(v) != n or len(a) != n:
            raise BatchCoreError(f"q, v, a have {n}, {len(v)}, {len(a)} rows")
        tau = np.empty((n, self.nv))
        jac = np.empty((n, self.n_feet, 3, self.nv))
        check(library().ciml_batch_inverse_dynamics(self.handle, n, address(q), address(v), address(a),
                                                    address(tau), address(jac)), "inverse_dynamics")
        return tau, jac

    def regressors(self, q: np.ndarray, v: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per sample: the feet's linear Jacobians (N × n_feet × 3 × nv), the joint torque regressor
        Y (N × nv × 10·n_bodies: RNEA = Y π) and ∂RNEA/∂q (N × nv × nv)."""
        q, v, a = _rows(q, self.nq, "q"), _rows(v, self.nv, "v"), _rows(a, self.nv, "a")
        n = len(q)
        if len(v) != n or len(a) != n:
            raise BatchCoreError(f"q, v, a have {n}, {len(v)}, {len(a)} rows")
        jac = np.empty((n, self.n_feet, 3, self.nv))
        Y = np.empty((n, self.nv, self.n_inertial))
        D = np.empty((n, self.nv, self.nv))
        check(library().ciml_batch_regressors(self.handle, n, address(q), address(v), address(a), address(jac),
                                              address(Y), address(D)), "regressors")
        return jac, Y, D

    def jacobian_variation_products(self, q: np.ndarray, sample: np.ndarray, foot: np.ndarray, dof: np.ndarray,
                                    lam: np.ndarray) -> np.ndarray:
        """Per item i: (∂J_f/∂q_d)ᵀ λ_i (nv), with J_f the linear rows of foot f's Jacobian
        (LOCAL_WORLD_ALIGNED) at q[sample[i]], f = foot[i] (an index into the robot's feet),
        d = dof[i] (a velocity coordinate), λ_i = lam[i] (3)."""
        q = _rows(q, self.nq, "q")
        sample, foot, dof = (np.ascontiguousarray(x, dtype=np.int64).ravel() for x in (sample, foot, dof))
        m = len(sample)
        lam = _rows(np.reshape(lam, (m, 3)), 3, "lam")
        if len(foot) != m or len(dof) != m:
            raise BatchCoreError(f"sample, foot, dof have {m}, {len(foot)}, {len(dof)} entries")
        out = np.empty((m, self.nv))
        check(library().ciml_batch_jacobian_variation_products(
            self.handle, m, address(sample), address(foot), address(dof), address(q), len(q), address(lam),
            address(out)),
            "jacobian_variation_products")
        return out
