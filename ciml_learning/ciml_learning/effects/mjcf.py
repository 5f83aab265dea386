"""An identified effect in MuJoCo's terms: the edits `ciml export-mjcf` makes to a user's MJCF.

Each effect type's `patch_mjcf` (ciml_learning/effects/<type>.py, its MuJoCo form) calls these
edits; elements are found by name and a name the file lacks is a one-line MjcfError. XML only (no
MuJoCo here): ciml_sim's verb compiles the result with mujoco.MjModel. Where MuJoCo's element is a
different model from CIML's plant (docs/DIAGNOSIS.md, "The answer as a MuJoCo model"):

- joint friction: `frictionloss` is a constraint with true stiction, made near-ideal as in CIML's
  plant (solreffriction/solimpfriction, unless the joint states its own), where the diagnosis'
  regressor is a tanh-smoothed sign; viscous `damping` is the same law, integrated implicitly;
- actuator lag: `dyntype="filterexact"` is the exact discretisation of T ȧ + a = u, CIML's plant the
  backward-Euler one (α = Δt/(T + Δt) against 1 − e^{−Δt/T} per 1 ms step: 1.3 % apart at T = 10 ms
  in the step's gain, the same steady state);
- a payload is a body welded to the base (a point mass: inertia 1e-9 kg m² on the diagonal, which
  MuJoCo needs positive).
Effects of one type add to what the file holds (a joint's damping, an actuator's bias), as
scenario effects add up.
"""
from __future__ import annotations

import xml.etree.ElementTree as ET

from ciml_learning.core.errors import CimlError

PAYLOAD_BODY = "ciml_payload"
POINT_INERTIA = 1e-9
"""[kg m²] the payload body's diagonal inertia (a point mass; MuJoCo needs it positive)."""
TORQUE_ACTUATORS = ("motor", "general")
"""Actuator elements whose force is gain · (lagged) control + bias: the ones a gain, offset or lag patch."""


class MjcfError(CimlError):
    """An MJCF the export cannot patch (a missing name, an actuator type it cannot express)."""


def _fmt(x: float) -> str:
    return f"{float(x):.17g}"


def _numbers(text: str | None, default: list[float]) -> list[float]:
    return [float(v) for v in text.split()] if text else list(default)


class MjcfPatch:
    """A parsed MJCF and the edits made to it (`text()` gives the result)."""

    def __init__(self, xml_text: str, source: str) -> None:
        if "<!DOCTYPE" in xml_text or "<!ENTITY" in xml_text:  # no entity expansion (XML bombs)
            raise MjcfError(f"{source}: MJCF with a DOCTYPE or ENTITY declaration is refused")
        try:
            self.root = ET.fromstring(xml_text)
        except ET.ParseError as err:
            raise MjcfError(f"{source}: not valid XML ({err})") from None
        if self.root.tag != "mujoco":
            raise MjcfError(f"{source}: not an MJCF file (root element <{self.root.tag}>, expected <mujoco>)")
        self.source = source

    def text(self) -> str:
        return ET.tostring(self.root, encoding="unicode")

    def _named(self, tag: str, name: str) -> ET.Element:
        found = [e for e in self.root.iter(tag) if e.get("name") == name]
        if len(found) != 1:
            names = sorted(str(e.get("name")) for e in self.root.iter(tag) if e.get("name"))
            shown = ", ".join(names[:12]) + (", ..." if len(names) > 12 else "")
            how = "no" if not found else "more than one"
            raise MjcfError(f"{self.source}: {how} <{tag} name=\"{name}\">; its {tag}s: {shown or 'none'}")
        return found[0]

    def joints_of(self, spec) -> list[str]:
        """A scenario's joint field as names: 'all' = every joint an actuator drives."""
        if spec == "all":
            return [str(a.get("joint")) for a in self._actuators() if a.get("joint")]
        return [spec] if isinstance(spec, str) else list(spec)

    def _actuators(self) -> list[ET.Element]:
        return [a for block in self.root.iter("actuator") for a in block]

    def add_joint_attribute(self, joint: str, attribute: str, value: float) -> None:
        """A joint's damping or frictionloss plus value (what the file states, 0 if it states none)."""
        j = self._named("joint", joint)
        j.set(attribute, _fmt(float(j.get(attribute, "0")) + value))

    def set_joint_default(self, joint: str, attribute: str, values) -> None:
        """A joint attribute set only where the file states none (the user's own choice wins)."""
        j = self._named("joint", joint)
        if j.get(attribute) is None:
            j.set(attribute, " ".join(_fmt(v) for v in values))

    def timestep(self) -> float:
        """The model's <option timestep> [s] (MuJoCo's default 0.002 where it states none)."""
        option = self.root.find("option")
        return float(option.get("timestep", "0.002")) if option is not None else 0.002

    def add_payload(self, mass: float, com) -> None:
        """A body welded to the base (the body of the free joint) with the payload's mass at com."""
        if any(e.get("name") == PAYLOAD_BODY for e in self.root.iter("body")):
            raise MjcfError(f"{self.source}: a body named {PAYLOAD_BODY} exists already")
        bases = [b for b in self.root.iter("body") if b.find("freejoint") is not None
                 or any(j.get("type") == "free" for j in b.findall("joint"))]
        if len(bases) != 1:
            raise MjcfError(f"{self.source}: expected one body with a free joint (the base), found {len(bases)}")
        body = ET.SubElement(bases[0], "body", {"name": PAYLOAD_BODY, "pos": " ".join(_fmt(c) for c in com)})
        ET.SubElement(body, "inertial", {"pos": "0 0 0", "mass": _fmt(mass),
                                         "diaginertia": " ".join([_fmt(POINT_INERTIA)] * 3)})

    def scale_body_inertial(self, body: str, scale: float) -> None:
        """The body's mass and inertia × scale (its CoM unchanged), as link_mass_scale acts."""
        inertial = self._named("body", body).find("inertial")
        if inertial is None:
            raise MjcfError(f"{self.source}: body {body} has no <inertial> (MuJoCo infers it from its geoms); "
                            "give it one to scale")
        inertial.set("mass", _fmt(float(inertial.get("mass", "0")) * scale))
        for key in ("diaginertia", "fullinertia"):
            if inertial.get(key):
                inertial.set(key, " ".join(_fmt(v * scale) for v in _numbers(inertial.get(key), [])))

    def _actuator(self, joint: str) -> ET.Element:
        """The joint's torque actuator, a <motor> turned into the equivalent <general> (gain 1, no bias)."""
        self._named("joint", joint)
        found = [a for a in self._actuators() if a.get("joint") == joint]
        if len(found) != 1:
            raise MjcfError(f"{self.source}: {'no' if not found else 'more than one'} actuator drives joint {joint}")
        a = found[0]
        if a.tag not in TORQUE_ACTUATORS:
            raise MjcfError(f"{self.source}: actuator of joint {joint} is a <{a.tag}>; a torque gain, offset or lag "
                            f"is exported to {' or '.join(TORQUE_ACTUATORS)} only")
        if a.tag == "motor":
            a.tag = "general"
        return a

    def scale_actuator_gain(self, joint: str, gain: float) -> None:
        a = self._actuator(joint)
        prm = _numbers(a.get("gainprm"), [1.0])
        prm[0] *= gain
        a.set("gainprm", " ".join(_fmt(v) for v in prm))

    def add_actuator_bias(self, joint: str, offset: float) -> None:
        """offset [Nm at the joint]: biasprm[0] += offset / gear (the force is gear · (gain · act + bias))."""
        a = self._actuator(joint)
        if a.get("biastype", "none") not in ("none", "affine"):
            raise MjcfError(f"{self.source}: actuator of joint {joint} has biastype {a.get('biastype')}")
        gear = _numbers(a.get("gear"), [1.0])[0]
        prm = _numbers(a.get("biasprm"), [0.0, 0.0, 0.0])
        prm[0] += offset / gear
        a.set("biastype", "affine")
        a.set("biasprm", " ".join(_fmt(v) for v in prm))

    def set_actuator_lag(self, joint: str, time_constant: float) -> None:
        a = self._actuator(joint)
        if a.get("dyntype", "none") not in ("none", "filterexact", "filter"):
            raise MjcfError(f"{self.source}: actuator of joint {joint} has dyntype {a.get('dyntype')}")
        before = _numbers(a.get("dynprm"), [0.0])[0] if a.get("dyntype", "none") != "none" else 0.0
        a.set("dyntype", "filterexact")
        a.set("dynprm", _fmt(before + time_constant))  # lag time constants add, as in a scenario
        a.set("actearly", "true")  # the force of a step uses the state after it, as CIML's plant does
