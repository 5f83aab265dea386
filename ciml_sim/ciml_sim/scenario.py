"""Scenarios: the unmodelled effects that make the simulation the "real robot" (DESIGN §5).

A scenario is a YAML file, validated on load: an unknown type, joint or link, a
missing, extra or out-of-range field gives a ScenarioError with one line naming the
field and the valid choices. The nominal model (Pinocchio) never sees a scenario.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Any

import yaml

from ciml_learning.errors import CimlError
from ciml_learning.robot import RobotDescription


class ScenarioError(CimlError):
    """A scenario file is missing or invalid."""


# type -> {field: (kind, lo, hi)}; kind: joint | joints | link | float | vec3
_CATALOGUE: dict[str, dict[str, tuple]] = {
    "payload": {"mass": ("float", 0.0, 100.0), "com": ("vec3", -1.0, 1.0)},
    "joint_coulomb_friction": {"joint": ("joints",), "value": ("float", 0.0, 100.0)},
    "joint_viscous_friction": {"joint": ("joints",), "value": ("float", 0.0, 100.0)},
    "actuator_lag": {"joints": ("joints",), "time_constant": ("float", 0.0, 0.2)},
    "torque_gain": {"joint": ("joints",), "value": ("float", 0.1, 2.0)},
    "torque_offset": {"joint": ("joints",), "value": ("float", -50.0, 50.0)},
    "link_mass_scale": {"link": ("link",), "value": ("float", 0.1, 5.0)},
    "encoder_offset": {"joint": ("joints",), "value": ("float", -0.2, 0.2)},
    "base_imu_tilt": {"roll": ("float", -0.2, 0.2), "pitch": ("float", -0.2, 0.2)},
    # outside the diagnosis' catalogue (used to check that it says "unexplained"):
    "joint_stribeck_friction": {"joint": ("joints",), "breakaway": ("float", 0.0, 100.0),
                                "coulomb": ("float", 0.0, 100.0), "velocity": ("float", 1e-3, 5.0)},
    "joint_spring": {"joint": ("joints",), "stiffness": ("float", 0.0, 1000.0), "rest": ("float", -3.2, 3.2)},
    "torque_ripple": {"joint": ("joints",), "amplitude": ("float", 0.0, 50.0), "period": ("float", 0.01, 6.3)},
}
EFFECT_TYPES = tuple(_CATALOGUE)
NOISE_FIELDS = ("q", "qd", "tau", "base_orientation", "base_position", "base_velocity")


@dataclass(frozen=True)
class Effect:
    """One injected effect; `joints` resolved to joint indices (or the link name)."""

    type: str
    params: dict[str, Any]
    joints: tuple[int, ...] = ()
    link: str | None = None

    @property
    def label(self) -> str:
        """Unique, readable label (used for /sim/effect/<label> ground truth only)."""
        where = self.link or "_".join(str(j) for j in self.joints) or "base"
        return f"{self.type}_{where}"


@dataclass(frozen=True)
class Scenario:
    name: str
    seed: int = 0
    sensor_noise: dict[str, float] = field(default_factory=dict)
    effects: tuple[Effect, ...] = ()

    def of_type(self, *types: str) -> list[Effect]:
        return [e for e in self.effects if e.type in types]


def nominal_scenario() -> Scenario:
    return Scenario(name="nominal")


def _resolve_joints(value, robot: RobotDescription, where: str) -> tuple[int, ...]:
    names = list(robot.joint_names) if value == "all" else ([value] if isinstance(value, str) else value)
    if not isinstance(names, list) or not names:
        raise ScenarioError(f"{where}: expected a joint name, a list of names or 'all'")
    out = []
    for n in names:
        if n not in robot.joint_names:
            raise ScenarioError(f"{where}: unknown joint {n!r}; valid: all, {', '.join(robot.joint_names)}")
        out.append(robot.joint_names.index(n))
    return tuple(out)


def parse_scenario(data: Any, robot: RobotDescription) -> Scenario:
    if not isinstance(data, dict):
        raise ScenarioError("scenario: expected a mapping with name, seed, sensor_noise, effects")
    extra = set(data) - {"name", "seed", "sensor_noise", "effects", "description"}
    if extra:
        raise ScenarioError(f"scenario: unknown field(s) {sorted(extra)}; valid: name, seed, sensor_noise, effects, description")
    noise = data.get("sensor_noise") or {}
    if not isinstance(noise, dict):
        raise ScenarioError("sensor_noise: expected a mapping of standard deviations")
    for k, v in noise.items():
        if k not in NOISE_FIELDS:
            raise ScenarioError(f"sensor_noise.{k}: unknown; valid: {', '.join(NOISE_FIELDS)}")
        if not isinstance(v, (int, float)) or not 0 <= v < 10:
            raise ScenarioError(f"sensor_noise.{k}: expected a standard deviation in [0, 10), got {v!r}")
    effects = []
    for i, e in enumerate(data.get("effects") or []):
        where = f"effects[{i}]"
        if not isinstance(e, dict) or "type" not in e:
            raise ScenarioError(f"{where}: expected a mapping with a 'type'")
        typ = e["type"]
        if typ not in _CATALOGUE:
            raise ScenarioError(f"{where}.type: unknown effect {typ!r}; valid: {', '.join(EFFECT_TYPES)}")
        spec = _CATALOGUE[typ]
        given = set(e) - {"type"}
        if given != set(spec):
            raise ScenarioError(f"{where} ({typ}): fields {sorted(given)}; expected exactly {sorted(spec)}")
        params, joints, link = {}, (), None
        for k, s in spec.items():
            v = e[k]
            if s[0] == "joints":
                joints = _resolve_joints(v, robot, f"{where}.{k}")
            elif s[0] == "link":
                if v not in robot.link_names:
                    raise ScenarioError(f"{where}.{k}: unknown link {v!r}; valid: {', '.join(robot.link_names)}")
                link = v
            elif s[0] == "vec3":
                if not (isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) for x in v)):
                    raise ScenarioError(f"{where}.{k}: expected [x, y, z] in metres")
                if any(not s[1] <= x <= s[2] for x in v):
                    raise ScenarioError(f"{where}.{k}: each component must be in [{s[1]}, {s[2]}]")
                params[k] = [float(x) for x in v]
            else:
                if not isinstance(v, (int, float)) or isinstance(v, bool) or not s[1] <= v <= s[2]:
                    raise ScenarioError(f"{where}.{k}: expected a number in [{s[1]}, {s[2]}], got {v!r}")
                params[k] = float(v)
        effects.append(Effect(typ, params, joints, link))
    seed = data.get("seed", 0)
    if not isinstance(seed, int):
        raise ScenarioError(f"seed: expected an integer, got {seed!r}")
    return Scenario(name=str(data.get("name", "unnamed")), seed=seed,
                    sensor_noise={k: float(v) for k, v in noise.items()}, effects=tuple(effects))


def load_scenario(path: str | os.PathLike, robot: RobotDescription) -> Scenario:
    try:
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
    except FileNotFoundError as err:
        raise ScenarioError(f"scenario file not found: {path}") from err
    except yaml.YAMLError as err:
        raise ScenarioError(f"scenario {path}: invalid YAML ({str(err).splitlines()[0]})") from err
    return parse_scenario(data, robot)


def scenario_dir() -> str:
    """Folder of the shipped scenarios (installed share/ciml_sim/config/scenarios, else the source tree)."""
    import sys

    for d in (os.path.join(sys.prefix, "share", "ciml_sim", "config", "scenarios"),
              os.path.join(os.path.dirname(__file__), "..", "config", "scenarios")):
        if os.path.isdir(d):
            return os.path.abspath(d)
    raise ScenarioError("shipped scenarios not found; run make install")
