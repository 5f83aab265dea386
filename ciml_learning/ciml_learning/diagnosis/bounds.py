"""Physical bounds of every catalogue parameter (docs/DIAGNOSIS.md), read from the effect registry.

A parameter outside its range is not a property of a robot: a 0.06 kg foot does not weigh two
tonnes, an encoder is not mounted 10° off, friction does not push. The identification fits inside
the ranges (bounded least squares, identification.bounded_least_squares), and an estimate that
ends on a bound that is not the parameter's null value ("no effect") is reported as "at bound —
not identified", with no confidence, never as an effect. Each effect type states its own range
(ciml_learning/effects/<type>.py: theta_bounds, physical_range, physical_violation); where a bound
scales with the robot it comes from its description (total mass, URDF torque limits τ_max,
FALLBACK_TORQUE_LIMIT where the URDF gives none).

The command-update sampling baseline (not an effect) is bounded here: theory gives
qd = −K_p Δt/2 ≤ 0, qdd = −K_d Δt/2 ≤ 0, udot = −Δt/2 ∈ [−MAX_TICK/2, 0] (Δt the controller tick).
"""
from __future__ import annotations

import numpy as np

from ciml_learning.effects import CATALOGUE, effect_type
from ciml_learning.effects.actuator_lag import MAX_LAG
from ciml_learning.effects.base import FRICTION_FRACTION, OFFSET_FRACTION, TORQUE_GAIN, torque_limits
from ciml_learning.effects.payload import PAYLOAD_MASS_FRACTION

MAX_TICK = 0.1
"""[s] longest controller tick of a log (the baseline's udot ≥ −MAX_TICK/2)."""
BASELINE = "command_update_sampling"

__all__ = ["BASELINE", "FRICTION_FRACTION", "MAX_LAG", "MAX_TICK", "OFFSET_FRACTION", "PAYLOAD_MASS_FRACTION",
           "TORQUE_GAIN", "parameter_bounds", "physical_ranges", "physical_violation", "torque_limits"]


def parameter_bounds(robot, cand_type: str, joint: str | None = None) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(lower, upper) of a candidate's linear parameters θ (the effect type's theta_bounds)."""
    if cand_type == BASELINE:
        return (-np.inf, -np.inf, -MAX_TICK / 2), (0.0, 0.0, 0.0)
    return effect_type(cand_type).theta_bounds(robot, joint)


def physical_ranges(robot) -> dict:
    """The bounds in the scenario's terms, for diagnosis.json (`bounds`) and the report."""
    out = {name: effect_type(name).physical_range(robot) for name in CATALOGUE}
    out[BASELINE] = {"qd": [None, 0.0], "qdd": [None, 0.0], "udot": [-MAX_TICK / 2, 0.0]}
    return out


def physical_violation(cand_type: str, params: dict) -> str | None:
    """Which physical parameter (in the scenario's terms) leaves its range after the conversion
    from θ (a lag T = c·g can exceed MAX_LAG while c is inside its box); None when all are inside."""
    return effect_type(cand_type).physical_violation(params)
