"""The controller's C++ core (ciml_control/cpp/control_core.cpp) and how compiled
(numba) code calls it.

The 250 Hz control step makes two Pinocchio passes and one proxsuite solve around a few
small matrix kernels. Called from Python each call costs more in wrappers than in
arithmetic; called from the compiled control step (ciml_control.compiled.control_step)
through their C addresses, they cost what the algorithms cost. The library is compiled
by tools/install.sh against the headers of the installed pin and proxsuite wheels
(Pinocchio for every dynamics quantity, proxsuite for every QP, as before; only the
language around them changed).

`ccall(fn, (p1, …, pn))` calls the C function at address fn with n pointer arguments
from compiled code; addresses are arguments, never compiled-in constants, so numba's
on-disk cache stays valid from one process to the next.

The ABI (the one place both sides cite; control_core.cpp's comments hold the same):
`FUNCTIONS` names each function compiled code calls and its pointer arguments.
Every argument is a pointer (handles from `Dynamics` / `QpSolvers`, `a.ctypes.data` of a
C-contiguous array); matrices are row-major float64, sizes and results int64, the caller
guarantees the sizes; no function raises (failures are status codes).
"""
from __future__ import annotations

import ctypes
import os
from functools import lru_cache

import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription

LIBRARY = os.path.join(os.path.dirname(os.path.abspath(__file__)), "libciml_control_core.so")


class NativeCoreError(CimlError):
    """The controller core is missing or refused its input."""


@lru_cache(maxsize=None)
def library() -> ctypes.CDLL:
    if not os.path.isfile(LIBRARY):
        raise NativeCoreError(f"the controller core {LIBRARY} is not built; run tools/install.sh")
    lib = ctypes.CDLL(LIBRARY)
    for name in ("ciml_dynamics_new", "ciml_qp_new"):
        getattr(lib, name).restype = ctypes.c_void_p
    return lib


@lru_cache(maxsize=None)
def address(name: str) -> int:
    """Address of the core's C function `name`."""
    ptr = ctypes.cast(getattr(library(), name), ctypes.c_void_p).value
    assert ptr is not None  # a resolved symbol is never NULL
    return ptr


FUNCTIONS = ("ciml_terms", "ciml_difference", "ciml_qp_solve", "ciml_qp_drop", "ciml_foot_kinematics",
             "ciml_foot_acceleration")
"""The core's C functions compiled code calls, in the order of function_table(); compiled
code indexes the table by the names below. Each takes these pointer arguments (nv, nq: the
robot's; nf: its feet; row-major float64 unless said):

TERMS              ciml_terms (Dynamics*, q[nq], v[nv], M[nv×nv] out (upper triangle), h[nv] out,
                   J[nf×3×nv] out (feet, linear, LOCAL_WORLD_ALIGNED))
DIFFERENCE         ciml_difference (Dynamics*, q0[nq], q1[nq], out[nv] = q1 ⊖ q0)
QP_SOLVE           ciml_qp_solve (QpSolvers*, sizes[4] int64 (n, n_eq, n_in, box), H[n×n], g[n], A[n_eq×n],
                   b[n_eq], C[n_in×n], l[n_in], u[n_in], lb[n], ub[n] (read only with box), x[n] out,
                   info[2] int64 out (status: 0 solved, −1 exception, else QPSolverOutput + 1; iterations))
QP_DROP            ciml_qp_drop (QpSolvers*, sizes[4] int64): forget the solver of that size
FOOT_KINEMATICS    ciml_foot_kinematics (Dynamics*, q[nq], J[nf×3×nv] out, feet[nf×3] out (world positions))
FOOT_ACCELERATION  ciml_foot_acceleration (Dynamics*, q[nq], v[nv], a[nv], out[nf×3] (classical, world-aligned))

The table is an int64 array, not a named tuple: numba types a named tuple argument in
Python on every call from Python (measured: several µs per call of the 250 Hz step), an
array in C; the index names are compile-time constants in the kernels."""
TERMS, DIFFERENCE, QP_SOLVE, QP_DROP, FOOT_KINEMATICS, FOOT_ACCELERATION = range(len(FUNCTIONS))


def function_table() -> np.ndarray:
    """Addresses of FUNCTIONS (int64), the table the compiled kernels index by TERMS, DIFFERENCE, …"""
    return np.array([address(n) for n in FUNCTIONS], dtype=np.int64)


@intrinsic
def ccall(typingctx, fn, args):
    """fn(*args) for the address fn of a C function void f(void*, …) taking len(args)
    pointers (args: a tuple of 64-bit integer addresses, e.g. handles and a.ctypes.data)."""
    if not isinstance(args, types.BaseTuple) or not all(isinstance(t, types.Integer) and t.bitwidth == 64
                                                         for t in args.types):
        return None
    n = len(args.types)
    sig = types.void(fn, args)

    def codegen(context, builder, signature, llargs):
        ptr = ir.IntType(8).as_pointer()
        fnty = ir.FunctionType(ir.VoidType(), [ptr] * n)
        f = builder.inttoptr(llargs[0], fnty.as_pointer())
        builder.call(f, [builder.inttoptr(builder.extract_value(llargs[1], i), ptr) for i in range(n)])
        return context.get_dummy_value()

    return sig, codegen


class Dynamics:
    """A Pinocchio model and data in the core: the robot's model (passed as Pinocchio's own
    archive, so it is the very model of `robot`, whatever was loaded) and its feet."""

    def __init__(self, robot: RobotDescription) -> None:
        lib = library()
        feet = np.array(robot.foot_frame_ids, dtype=np.int64)
        n = np.array([feet.size], dtype=np.int64)
        handle = lib.ciml_dynamics_new(ctypes.c_char_p(robot.model.saveToString().encode()),
                                       ctypes.c_void_p(feet.ctypes.data), ctypes.c_void_p(n.ctypes.data))
        if not handle:
            raise NativeCoreError("the controller core could not load the robot model")
        self.handle = int(handle)
        self._free = lib.ciml_dynamics_free

    def __del__(self) -> None:
        if getattr(self, "handle", 0):
            self._free(ctypes.c_void_p(self.handle))
            self.handle = 0


class QpSolvers:
    """proxsuite dense solvers in the core, one per problem size (ciml_qp_solve)."""

    def __init__(self, eps_abs: float, max_iter: int) -> None:
        lib = library()
        e, m = np.array([eps_abs], dtype=float), np.array([max_iter], dtype=np.int64)
        self.handle = int(lib.ciml_qp_new(ctypes.c_void_p(e.ctypes.data), ctypes.c_void_p(m.ctypes.data)))
        self._free = lib.ciml_qp_free
        self._count = lib.ciml_qp_count

    def __len__(self) -> int:
        out = np.zeros(1, dtype=np.int64)
        self._count(ctypes.c_void_p(self.handle), ctypes.c_void_p(out.ctypes.data))
        return int(out[0])

    def __del__(self) -> None:
        if getattr(self, "handle", 0):
            self._free(ctypes.c_void_p(self.handle))
            self.handle = 0
