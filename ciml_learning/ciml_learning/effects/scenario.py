"""The scenario format (docs/ARCHITECTURE.md §5), defined beside the registry so that both the
simulator (ciml_sim.scenario loads and validates it) and the diagnosis (which writes the identified
effects as a scenario, `identified_scenario.yaml`) reach it; ciml_learning never imports ciml_sim.

A scenario maps TOP_LEVEL keys: name, robot (the shipped robot it was written for, '' = any),
seed, sensor_noise (standard deviations of NOISE_FIELDS), effects (each {type, <its fields>}: the
registry's fields, units and ranges) and a description.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ciml_learning.effects import effect_type

TOP_LEVEL = ("name", "robot", "seed", "sensor_noise", "effects", "description")
NOISE_FIELDS: tuple[str, ...] = ("q", "qd", "tau", "base_orientation", "base_position", "base_velocity")
"""Sensor-noise standard deviations: q [rad], qd [rad/s], tau [Nm], base_orientation [rad],
base_position [m], base_velocity [m/s and rad/s]."""


def scenario_effect(effect: dict) -> dict:
    """A diagnosed effect ({type, joint|joints|link, params}, diagnosis.json) as a scenario entry:
    the type's fields, the location under its own field name, the parameters in its units."""
    kind = effect_type(effect.get("type"))
    out: dict[str, Any] = {"type": kind.name}
    for name, f in kind.fields.items():
        if f.kind == "joints":
            out[name] = effect.get("joint") or effect.get("joints")
        elif f.kind == "link":
            out[name] = effect["link"]
        else:
            v = effect["params"][name]
            out[name] = [float(x) for x in v] if isinstance(v, list) else float(v)
    return out


def outside_range(entry: dict) -> str | None:
    """Which number of a scenario entry the simulator would refuse (its field's range), or None."""
    kind = effect_type(entry["type"])
    for name, f in kind.fields.items():
        if f.kind in ("float", "vec3"):
            v = np.atleast_1d(np.asarray(entry[name], float))
            if np.any(v < f.lo) or np.any(v > f.hi):
                return f"{entry['type']}.{name} = {entry[name]} outside the simulator's [{f.lo}, {f.hi}]"
    return kind.check(entry)
