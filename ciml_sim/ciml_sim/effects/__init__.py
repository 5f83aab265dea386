"""The simulator's side of the effect registry: how ciml_sim applies each registered effect type
(ciml_learning.effects), one module per name (base.py: where in the plant's chain each acts)."""
from __future__ import annotations

from ciml_learning.effects import EFFECTS as REGISTERED

from . import (
    actuator_lag,
    base_imu_tilt,
    encoder_offset,
    joint_coulomb_friction,
    joint_spring,
    joint_stribeck_friction,
    joint_viscous_friction,
    link_mass_scale,
    payload,
    torque_gain,
    torque_offset,
    torque_ripple,
    torque_sensor_gain,
    torque_sensor_offset,
    torque_sensor_ripple,
)
from .base import SimEffect, Truth

SIM_EFFECTS: dict[str, SimEffect] = {m.EFFECT.name: m.EFFECT for m in (
    payload, joint_coulomb_friction, joint_viscous_friction, actuator_lag, torque_gain, torque_offset,
    link_mass_scale, encoder_offset, base_imu_tilt, torque_sensor_gain, torque_sensor_offset,
    joint_stribeck_friction, joint_spring, torque_ripple, torque_sensor_ripple)}
if set(SIM_EFFECTS) != set(REGISTERED):  # pragma: no cover - a programming error
    raise ImportError(f"registered effects without a simulation (or the reverse): "
                      f"{sorted(set(SIM_EFFECTS) ^ set(REGISTERED))}")

__all__ = ["SIM_EFFECTS", "SimEffect", "Truth"]
