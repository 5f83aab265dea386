"""Scenarios: the unmodelled effects that make the simulation the "real robot" (docs/ARCHITECTURE.md §5).

A scenario is a YAML file, validated on load against the effect registry
(ciml_learning.effects: each type's fields, units and ranges): an unknown type, joint or
link, a missing, extra or out-of-range field gives a ScenarioError with one line naming
the field and the valid choices. The nominal model (Pinocchio) never sees a scenario.

Effects combine. Several effects of one type on the same joint (or link) add up:
frictions and offsets add, gains and link-mass scales add their deviations from 1
(g = 1 + Σ(gᵢ − 1)), lag time constants add; so every effect's share of the
generalized force is well defined (ciml_sim.plant.GroundTruth.effect_forces).
"""
from __future__ import annotations

import math
import os
import re
import sys
from dataclasses import dataclass, field
from typing import Any

from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription
from ciml_learning.effects import CATALOGUE, EFFECTS, MEASUREMENT_ONLY, OUT_OF_CATALOGUE, Field
from ciml_learning.effects.scenario import NOISE_FIELDS, TOP_LEVEL


class ScenarioError(CimlError):
    """A scenario file is missing or invalid."""


EFFECT_TYPES: tuple[str, ...] = tuple(EFFECTS)
"""Every effect type the simulator knows: the registry's (ciml_learning.effects), each simulated by
its module of ciml_sim.effects."""
CATALOGUE_TYPES: tuple[str, ...] = CATALOGUE
"""The effect types the diagnosis has candidates for."""
OUT_OF_CATALOGUE_TYPES: tuple[str, ...] = OUT_OF_CATALOGUE
MEASUREMENT_ONLY_TYPES: tuple[str, ...] = MEASUREMENT_ONLY
"""Effects that bias a measurement and exert no force."""


@dataclass(frozen=True)
class Effect:
    """One injected effect.

    joints: indices into robot.joint_names it acts on (empty for base and link effects);
    link: the URDF link of a link effect; label: a unique, topic-safe name
    (`<type>`, `<type>_<joint>`, `<type>_all`, `<type>_<link>`; `_2`, `_3` … on repeats),
    used only for the /sim/effect/<label> ground truth.
    """

    type: str
    params: dict[str, Any]
    joints: tuple[int, ...] = ()
    link: str | None = None
    label: str = ""


@dataclass(frozen=True)
class Scenario:
    """robot: the shipped robot profile the scenario was written for ('' = any robot: its effects
    name no joint or link); the live bridge refuses a scenario of another robot."""

    name: str
    seed: int = 0
    sensor_noise: dict[str, float] = field(default_factory=dict)
    effects: tuple[Effect, ...] = ()
    robot: str = ""

    def of_type(self, *types: str) -> list[Effect]:
        return [e for e in self.effects if e.type in types]


def nominal_scenario() -> Scenario:
    """No effect, no noise: the simulation matches the nominal model."""
    return Scenario(name="nominal")


def _resolve_joints(value: Any, robot: RobotDescription, where: str) -> tuple[tuple[int, ...], str]:
    """(joint indices, label suffix) of a joint field: a name, a list of names or 'all'."""
    valid = f"valid: all, {', '.join(robot.joint_names)}"
    if value == "all":
        return tuple(range(robot.n_joints)), "all"
    names = [value] if isinstance(value, str) else value
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise ScenarioError(f"{where}: expected a joint name, a list of joint names or 'all'; {valid}")
    out = []
    for n in names:
        if n not in robot.joint_names:
            raise ScenarioError(f"{where}: unknown joint {n!r}; {valid}")
        if robot.joint_names.index(n) in out:
            raise ScenarioError(f"{where}: joint {n!r} listed twice")
        out.append(robot.joint_names.index(n))
    return tuple(out), "_".join(n.removesuffix("_joint") for n in names)


def _number(v: Any, lo: float, hi: float, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ScenarioError(f"{where}: expected a number in [{lo}, {hi}], got {v!r}")
    return float(v)


def _parse_effect(e: Any, i: int, robot: RobotDescription) -> tuple[Effect, str]:
    where = f"effects[{i}]"
    if not isinstance(e, dict) or "type" not in e:
        raise ScenarioError(f"{where}: expected a mapping with a 'type'; valid types: {', '.join(EFFECT_TYPES)}")
    typ = e["type"]
    if not isinstance(typ, str) or typ not in EFFECTS:
        raise ScenarioError(f"{where}.type: unknown effect {typ!r}; valid: {', '.join(EFFECT_TYPES)}")
    spec: dict[str, Field] = EFFECTS[typ].fields
    given = set(e) - {"type"}
    unknown, missing = sorted(given - set(spec)), sorted(set(spec) - given)
    if unknown:
        raise ScenarioError(f"{where} ({typ}): unknown field(s) {', '.join(unknown)}; valid: {', '.join(spec)}")
    if missing:
        raise ScenarioError(f"{where} ({typ}): missing field(s) {', '.join(missing)}; required: {', '.join(spec)}")
    params: dict[str, Any] = {}
    joints: tuple[int, ...] = ()
    link = None
    suffix = ""
    for k, s in spec.items():
        v = e[k]
        w = f"{where}.{k}"
        if s.kind == "joints":
            joints, suffix = _resolve_joints(v, robot, w)
        elif s.kind == "link":
            if v not in robot.link_names:
                raise ScenarioError(f"{w}: unknown link {v!r}; valid: {', '.join(robot.link_names)}")
            link = suffix = v
        elif s.kind == "vec3":
            if not (isinstance(v, list) and len(v) == 3):
                raise ScenarioError(f"{w}: expected [x, y, z] in metres, each in [{s.lo}, {s.hi}], got {v!r}")
            params[k] = [_number(x, s.lo, s.hi, f"{w}[{n}]") for n, x in enumerate(v)]
        else:
            params[k] = _number(v, s.lo, s.hi, w)
    problem = EFFECTS[typ].check(params)
    if problem is not None:
        raise ScenarioError(f"{where}.{problem}")
    label = re.sub(r"[^A-Za-z0-9_]", "_", f"{typ}_{suffix}" if suffix else typ)
    return Effect(typ, params, joints, link), label


def parse_scenario(data: Any, robot: RobotDescription) -> Scenario:
    """Validate a scenario mapping (as loaded from YAML) against the robot."""
    if not isinstance(data, dict):
        raise ScenarioError(f"scenario: expected a mapping with keys {', '.join(TOP_LEVEL)}")
    extra = sorted(set(data) - set(TOP_LEVEL))
    if extra:
        raise ScenarioError(f"scenario: unknown field(s) {', '.join(map(str, extra))}; valid: {', '.join(TOP_LEVEL)}")
    name = data.get("name", "unnamed")
    if not isinstance(name, str) or not name:
        raise ScenarioError(f"name: expected a non-empty string, got {name!r}")
    noise = data.get("sensor_noise") or {}
    if not isinstance(noise, dict):
        raise ScenarioError("sensor_noise: expected a mapping of standard deviations; "
                            f"valid keys: {', '.join(NOISE_FIELDS)}")
    for k, v in noise.items():
        if k not in NOISE_FIELDS:
            raise ScenarioError(f"sensor_noise.{k}: unknown; valid: {', '.join(NOISE_FIELDS)}")
        _number(v, 0.0, 10.0, f"sensor_noise.{k}")
    raw_effects = data.get("effects") or []
    if not isinstance(raw_effects, list):
        raise ScenarioError("effects: expected a list of effects, each a mapping with a 'type'")
    effects = []
    used: dict[str, int] = {}
    for i, e in enumerate(raw_effects):
        effect, label = _parse_effect(e, i, robot)
        used[label] = used.get(label, 0) + 1
        if used[label] > 1:
            label = f"{label}_{used[label]}"
        effects.append(Effect(effect.type, effect.params, effect.joints, effect.link, label))
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ScenarioError(f"seed: expected a non-negative integer, got {seed!r}")
    robot_name = data.get("robot", "")
    if not isinstance(robot_name, str):
        raise ScenarioError(f"robot: expected a robot's name (hyq, go1, ...), got {robot_name!r}")
    return Scenario(name=name, seed=seed, sensor_noise={k: float(v) for k, v in noise.items()}, effects=tuple(effects),
                    robot=robot_name)


def load_scenario(path: str | os.PathLike, robot: RobotDescription) -> Scenario:
    """Load and validate a scenario YAML file (size and alias-expansion limits: fileio.load_yaml_bounded)."""
    from ciml_learning.core.fileio import InputFileError, load_yaml_bounded

    try:
        data = load_yaml_bounded(str(path), "scenario file", max_bytes=256 * 1024, max_nodes=20_000)
    except InputFileError as err:
        raise ScenarioError(str(err)) from None
    try:
        return parse_scenario(data, robot)
    except ScenarioError as err:
        raise ScenarioError(f"scenario {path}: {err}") from err


def scenario_dir() -> str:
    """Folder of the shipped scenarios (the source tree of an editable install, else share/ciml_sim)."""
    for d in (os.path.join(os.path.dirname(__file__), "..", "config", "scenarios"),
              os.path.join(sys.prefix, "share", "ciml_sim", "config", "scenarios")):
        if os.path.isdir(d):
            return os.path.abspath(d)
    raise ScenarioError("shipped scenarios not found; run make install")


def shipped_scenarios() -> tuple[str, ...]:
    return tuple(sorted(f[:-5] for f in os.listdir(scenario_dir()) if f.endswith(".yaml")))


def resolve_scenario(spec: str, robot: RobotDescription) -> Scenario:
    """A scenario from a YAML path, or the name of a shipped scenario ('nominal', 'default_gap', …)."""
    if os.path.isfile(spec):
        return load_scenario(spec, robot)
    if os.sep not in spec and not spec.endswith(".yaml"):
        path = os.path.join(scenario_dir(), f"{spec}.yaml")
        if os.path.isfile(path):
            return load_scenario(path, robot)
    raise ScenarioError(f"scenario file not found: {spec}; give a YAML path or a shipped scenario: "
                        f"{', '.join(shipped_scenarios())}")


def scenario_of_robot(spec: str, robot_name: str, robot: RobotDescription) -> Scenario:
    """The scenario `spec` for the robot named `robot_name` (a profile's name), as the live bridge
    takes it: '' = the shipped scenario written for that robot (its `robot:` key: hyq default_gap,
    go1 go1_gap), nominal when none is; a scenario written for another robot is refused in one line."""
    if not spec:
        for name in shipped_scenarios():
            path = os.path.join(scenario_dir(), f"{name}.yaml")
            if _robot_key(path) == robot_name:
                return load_scenario(path, robot)
        return nominal_scenario()
    path = spec if os.path.isfile(spec) else os.path.join(scenario_dir(), f"{spec}.yaml")
    written_for = _robot_key(path) if os.path.isfile(path) else ""
    if written_for and written_for != robot_name:
        raise ScenarioError(f"scenario {spec} is for robot {written_for}, not {robot_name}: give robot:={written_for} "
                            f"or a scenario of {robot_name}")
    return resolve_scenario(spec, robot)


def _robot_key(path: str) -> str:
    """The `robot:` key of a scenario file ('' without one; a malformed file is left to load_scenario)."""
    from ciml_learning.core.fileio import InputFileError, load_yaml_bounded

    try:
        data = load_yaml_bounded(path, "scenario file", max_bytes=256 * 1024, max_nodes=20_000)
    except InputFileError:
        return ""
    value = data.get("robot", "") if isinstance(data, dict) else ""
    return value if isinstance(value, str) else ""
