"""One parameter schema per node (the generate_parameter_library idea, in Python).

A node's schema is written once (`NodeSchema`, in `<package>/node_params.py`); from it come
- the node's declare() calls with descriptions, ranges and read_only flags
  (ciml_learning.ros.ros_common.declare_schema) and the checks of its on-set callback,
- its deployment file `config/<node>.yaml` (`ros__parameters`), and
- the Markdown table of the package README (`tools/param_docs.py` writes and checks both).

A parameter is either reconfigurable at run time (`read_only=False`: the node's apply
callback makes a set take effect) or read-only (rclpy refuses a set): never "successful and
ignored". No rclpy here, so the schema is testable and usable by tools without a ROS context.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

Value = bool | int | float | str


@dataclass(frozen=True)
class Param:
    """One parameter: name, default (its type is the parameter's type), description, unit (SI),
    closed range [lo, hi] for numbers, allowed choices for strings, and whether it is
    read-only after start. `deploy` is the value of the shipped config/<node>.yaml when it
    differs from the default (None: the default)."""

    name: str
    default: Value
    description: str
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = True
    deploy: Value | None = None

    def __post_init__(self) -> None:
        problem = self.check(self.default)
        if problem:
            raise ValueError(f"parameter {self.name}: default {self.default!r}: {problem}")
        if self.deploy is not None and self.check(self.deploy):
            raise ValueError(f"parameter {self.name}: deploy {self.deploy!r}: {self.check(self.deploy)}")

    @property
    def type_name(self) -> str:
        return {bool: "bool", int: "int", float: "double", str: "string"}[type(self.default)]

    def check(self, value: Any) -> str | None:
        """Why `value` is not allowed (None if it is): type, finiteness, range, choices."""
        kind = type(self.default)
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if type(value) is not kind:
            return f"expected a {self.type_name}, got {type(value).__name__} {value!r}"
        if isinstance(value, float) and not math.isfinite(value):
            return "must be finite"
        if self.lo is not None and isinstance(value, (int, float)) and value < self.lo:
            return f"{value!r} is below the minimum {self.lo:g}"
        if self.hi is not None and isinstance(value, (int, float)) and value > self.hi:
            return f"{value!r} is above the maximum {self.hi:g}"
        if self.choices and value not in self.choices:
            return f"{value!r} is not one of: {', '.join(self.choices)}"
        return None

    def description_line(self) -> str:
        return f"{self.description} [{self.unit}]" if self.unit else self.description

    def constraints_line(self) -> str:
        parts = []
        if self.lo is not None or self.hi is not None:
            parts.append(f"range [{_num(self.lo)}, {_num(self.hi)}]")
        if self.choices:
            parts.append("one of: " + ", ".join(self.choices))
        parts.append("read-only after start" if self.read_only else "reconfigurable at run time")
        return "; ".join(parts)


def _num(x: float | None) -> str:
    return "-inf" if x is None else f"{x:g}"


def _yaml_value(v: Value) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        text = repr(v)
        if "e" in text and "." not in text.split("e")[0]:  # YAML 1.1 floats need a dot ("1.0e-05")
            mantissa, exponent = text.split("e")
            text = f"{mantissa}.0e{exponent}"
        return text
    if isinstance(v, int):
        return str(v)
    return json.dumps(v)  # a quoted YAML scalar ("" stays a string)


@dataclass(frozen=True)
class NodeSchema:
    """Every parameter of one node (`package`/`node`), in declaration order."""

    package: str
    node: str
    summary: str
    params: tuple[Param, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        names = [p.name for p in self.params]
        if len(set(names)) != len(names):
            raise ValueError(f"{self.node}: duplicate parameter names in {names}")

    def get(self, name: str) -> Param | None:
        return next((p for p in self.params if p.name == name), None)

    @property
    def defaults(self) -> dict[str, Value]:
        return {p.name: p.default for p in self.params}

    def deployment_yaml(self) -> str:
        """config/<node>.yaml: the deployment values under `ros__parameters`, one commented line each."""
        lines = [
            f"# Parameters of {self.package}/{self.node}: {self.summary}",
            "# Generated from the node's schema (ciml_*/node_params.py) by tools/param_docs.py: edit the schema.",
            f"#   ros2 run {self.package} {self.node} --ros-args --params-file config/{self.node}.yaml",
            f"{self.node}:",
            "  ros__parameters:",
        ]
        width = max((len(p.name) + len(_yaml_value(p.deploy if p.deploy is not None else p.default))
                     for p in self.params), default=0) + 2
        for p in self.params:
            value = _yaml_value(p.deploy if p.deploy is not None else p.default)
            entry = f"{p.name}: {value}"
            note = p.description_line() + ("" if p.read_only else " (reconfigurable)")
            lines.append(f"    {entry.ljust(width)}  # {note}")
        return "\n".join(lines) + "\n"

    def markdown_table(self) -> str:
        """The README table: name, type, default, range or choices, run-time behaviour, description."""
        rows = [f"**`{self.node}`** — {self.summary}", "",
                "| Parameter | Type | Default | Range / choices | At run time | Description |",
                "|---|---|---|---|---|---|"]
        for p in self.params:
            if p.choices:
                allowed = ", ".join(f"`{c}`" for c in p.choices)
            elif p.lo is not None or p.hi is not None:
                allowed = f"[{_num(p.lo)}, {_num(p.hi)}]"
            else:
                allowed = ""
            rows.append(f"| `{p.name}` | {p.type_name} | `{_yaml_value(p.default)}` | {allowed} | "
                        f"{'read-only' if p.read_only else 'reconfigurable'} | {p.description_line()} |")
        return "\n".join(rows) + "\n"
