"""The effect registry: every unmodelled effect type, one module each (docs/ARCHITECTURE.md §5).

EFFECTS maps a type's name to its module's EffectType (fields and units, bounds, null value,
candidate columns, θ ↔ physical conversion, report wording, MuJoCo form). Scenario loading
(ciml_sim.scenario), the diagnosis (candidates, bounds, conversion, report), the identified
scenario and the MJCF export read it; ciml_sim registers how it simulates each name
(ciml_sim.effects). Like the learners' registry, it is the allow-list of the names files may hold.
"""
from __future__ import annotations

from ciml_learning.core.errors import CimlError
from ciml_learning.effects import (
    actuator_lag,
    base_imu_tilt,
    encoder_offset,
    joint_coulomb_friction,
    joint_stribeck_friction,
    joint_viscous_friction,
    link_mass_scale,
    payload,
    probes,
    torque_gain,
    torque_offset,
    torque_sensor_gain,
    torque_sensor_offset,
)
from ciml_learning.effects.base import Candidate, Conversion, EffectType, Field, Refinement

_ALL: tuple[EffectType, ...] = (
    payload.EFFECT, joint_coulomb_friction.EFFECT, joint_viscous_friction.EFFECT, actuator_lag.EFFECT,
    torque_gain.EFFECT, torque_offset.EFFECT, link_mass_scale.EFFECT, encoder_offset.EFFECT, base_imu_tilt.EFFECT,
    torque_sensor_gain.EFFECT, torque_sensor_offset.EFFECT, joint_stribeck_friction.EFFECT, *probes.EFFECTS,
)
EFFECTS: dict[str, EffectType] = {e.name: e for e in _ALL}
CATALOGUE: tuple[str, ...] = tuple(e.name for e in _ALL if e.in_catalogue)
"""The types the diagnosis has candidates for."""
OUT_OF_CATALOGUE: tuple[str, ...] = tuple(e.name for e in _ALL if not e.in_catalogue)
MEASUREMENT_ONLY: tuple[str, ...] = tuple(e.name for e in _ALL if e.measurement_only)
"""Types that bias a measurement and exert no force (the driver's calibration, not physics)."""


class EffectTypeError(CimlError):
    """An effect type name that is not registered."""


def effect_type(name: object) -> EffectType:
    """The registered type of a name; EffectTypeError naming the valid ones otherwise."""
    try:
        return EFFECTS[name]  # type: ignore[index]
    except (KeyError, TypeError):
        raise EffectTypeError(f"unknown effect type {name!r}; valid: {', '.join(EFFECTS)}") from None


__all__ = ["CATALOGUE", "EFFECTS", "MEASUREMENT_ONLY", "OUT_OF_CATALOGUE", "Candidate", "Conversion", "EffectType",
           "EffectTypeError", "Field", "Refinement", "effect_type"]
