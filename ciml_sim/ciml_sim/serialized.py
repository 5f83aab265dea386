"""Fast CDR serialisation of the simulation's messages: fixed-layout templates.

A sample's messages keep their layout from one tick to the next: the same joint, foot
and DoF names, frame ids and array lengths; only the stamp and the numbers change. A
`MessageTemplate` serialises one prototype message with rclpy once, finds where each
numeric field lives in the CDR bytes, and afterwards writes new values straight into a
copy of those bytes — a few µs instead of building rclpy objects (an Odometry alone
takes ~50 µs to construct) and serialising them.

Exactness: rclpy's CDR leaves the alignment padding between fields uninitialised (the
same message serialised twice can differ there), so the templates use the canonical
form: rclpy's bytes read back and written again by rosbags (ciml_learning.logs.bagio's
typestore), which zeroes the padding — the same message for every reader, and
deterministic bags. Each template is checked at construction against that canonical
serialisation of the same message with random values (byte-identical, else
`TemplateError`), and the slot positions are found so that a wrong one cannot match
(see `_locate`). Values are written as the message's CDR types: float64 little-endian,
bool as one byte 0/1, stamps as int32 sec + uint32 nanosec.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import RobotDescription

STAMP = "stamp"
"""Slot kind of a builtin_interfaces/Time (header stamp, /clock)."""


class TemplateError(CimlError):
    """A message does not have a fixed layout, or the template differs from rclpy's bytes."""


def _serialize(msg) -> bytes:
    """Canonical CDR of an rclpy message: rclpy's serialisation with zeroed padding."""
    from rclpy.serialization import serialize_message

    from ciml_learning.logs.bagio import typestore

    cls = type(msg)
    typename = f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"
    store = typestore()
    return bytes(store.serialize_cdr(store.deserialize_cdr(serialize_message(msg), typename), typename))


def _stamp_bytes(ns: int) -> bytes:
    return np.array([ns // 1_000_000_000], "<i4").tobytes() + np.array([ns % 1_000_000_000], "<u4").tobytes()


class MessageTemplate:
    """Canonical CDR bytes of `build(stamp_ns, *arrays)` with the stamp and arrays patched in place.

    slots: the kinds of build's arguments in order: STAMP, or (numpy dtype, count) for an
    array written as `count` consecutive CDR values ('<f8' float64, '?' bool). Every array
    argument must occupy consecutive bytes of the message (a float64[] field, or the x, y,
    z (w) doubles of a Point, Vector3 or Quaternion).
    """

    def __init__(self, build: Callable[..., object], slots: Sequence[str | tuple[str, int]], seed: int = 0) -> None:
        self.build = build
        self.slots = [s if s == STAMP else (np.dtype(s[0]), int(s[1])) for s in slots]
        if not self.slots or self.slots[0] != STAMP:
            raise TemplateError("the first slot of a message template is its stamp")
        rng = np.random.default_rng(seed)
        a_vals, b_vals = zip(*(self._sentinels(s, rng) for s in self.slots))
        base = _serialize(build(*a_vals))
        self._buf = bytearray(base)
        self._views: list[np.ndarray] = []
        for k, slot in enumerate(self.slots):
            args = list(a_vals)
            args[k] = b_vals[k]
            other = _serialize(build(*args))
            if len(other) != len(base):
                raise TemplateError("message layout changes with its values (not a fixed-layout message)")
            a_bytes, b_bytes = self._pack(slot, a_vals[k]), self._pack(slot, b_vals[k])
            off = _locate(base, other, a_bytes, b_bytes)
            if isinstance(slot, tuple):
                dtype, count = slot
                self._views.append(np.frombuffer(self._buf, dtype, count=count, offset=off))
            else:  # STAMP
                self._views.append(np.frombuffer(self._buf, "<u4", count=2, offset=off))
        for _ in range(3):  # byte-identical to the canonical serialisation for random values
            vals = [self._random(s, rng) for s in self.slots]
            if self.serialize(*vals) != _serialize(build(*vals)):
                raise TemplateError("template bytes differ from rclpy's serialisation")

    @staticmethod
    def _pack(slot, value) -> bytes:
        if slot == STAMP:
            return _stamp_bytes(int(value))
        dtype, count = slot
        return np.asarray(value, dtype=dtype).tobytes()

    @staticmethod
    def _random(slot, rng: np.random.Generator):
        if slot == STAMP:
            return int(rng.integers(0, 2**31 - 1)) * 1_000_000_000 + int(rng.integers(0, 10**9))
        dtype, count = slot
        if dtype.kind == "b":
            return rng.integers(0, 2, count).astype(bool)
        return rng.normal(0.0, 10.0, count)

    def _sentinels(self, slot, rng: np.random.Generator) -> tuple:
        """Two values of a slot whose packed bytes differ at every position."""
        if slot != STAMP and slot[0].kind == "b":
            a = np.arange(slot[1]) % 2 == 0
            return a, ~a
        if slot != STAMP and slot[0] == np.dtype("<f8"):
            # random bits with the top byte 0x3F (|a| < 2, finite); b = the bitwise complement
            # (top byte 0xC0: −2¹⁶ < b ≤ −2, finite)
            bits = rng.integers(0, 256, (slot[1], 8), dtype=np.uint8)
            bits[:, 7] = 0x3F
            return bits.view("<f8").ravel().copy(), (~bits).view("<f8").ravel().copy()
        for _ in range(1000):
            a, b = self._random(slot, rng), self._random(slot, rng)
            pa, pb = self._pack(slot, a), self._pack(slot, b)
            if all(x != y for x, y in zip(pa, pb)):
                return a, b
        raise TemplateError("no sentinel values found")  # pragma: no cover - probability ~0

    def serialize(self, stamp_ns: int, *arrays) -> bytes:
        """The message's canonical CDR bytes for these values (rclpy's serialize_message
        with zeroed padding)."""
        views = self._views
        sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
        if not 0 <= sec < 2**31:
            raise TemplateError(f"stamp {stamp_ns} ns is outside the int32 seconds of builtin_interfaces/Time")
        stamp = views[0]  # int32 sec written as uint32: the same bytes for 0 ≤ sec < 2³¹
        stamp[0], stamp[1] = sec, nanosec
        for view, value in zip(views[1:], arrays):
            view[:] = value
        return bytes(self._buf)


def _locate(base: bytes, other: bytes, a: bytes, b: bytes) -> int:
    """The one offset where `base` holds `a` and `other` holds `b`.

    base and other differ only in this slot, and a and b differ at every byte, so a
    window that is not exactly the slot cannot match both: outside the slot the two
    buffers agree while a and b do not.
    """
    n = len(a)
    diff = [i for i, (x, y) in enumerate(zip(base, other)) if x != y]
    if not diff:
        raise TemplateError("a slot's value does not appear in the serialised message")
    found = [off for off in range(max(0, diff[-1] - n + 1), diff[0] + 1)
             if base[off:off + n] == a and other[off:off + n] == b]
    if len(found) != 1:
        raise TemplateError(f"a slot is not a contiguous run of values ({len(found)} candidate offsets)")
    return found[0]


class SampleSerializer:
    """CDR bytes of one headless sample's messages (the live topics and /sim/), by template.

    The messages of ciml_learning.core.conversions and ciml_sim.recorder.ground_truth_messages,
    serialised by rclpy with zeroed padding (checked at construction).
    """

    def __init__(self, robot: RobotDescription, effect_labels: Sequence[str] = ()) -> None:
        from ciml_msgs.msg import ContactForces, GeneralizedForce
        from rosgraph_msgs.msg import Clock

        nj, nf, nv = robot.n_joints, robot.n_feet, robot.nv
        f8 = "<f8"
        self.clock = MessageTemplate(lambda ns: Clock(clock=cv.stamp_msg(ns)), [STAMP])
        self.joint_states = MessageTemplate(
            lambda ns, q, qd, tau: cv.joint_state_msg(robot, ns, q, qd, tau), [STAMP, (f8, nj), (f8, nj), (f8, nj)])
        self.base_state = MessageTemplate(
            lambda ns, p, quat, lin, ang: cv.odometry_msg(ns, p, quat, lin, ang),
            [STAMP, (f8, 3), (f8, 4), (f8, 3), (f8, 3)])
        self.contact_state = MessageTemplate(lambda ns, c: cv.contact_state_msg(robot, ns, c), [STAMP, ("?", nf)])

        def command(ns, ff, fl, qt, qdt, kp, kd):
            return cv.torque_command_msg(robot, ns, cv.TorqueCommandArrays(0, ff, fl, qt, qdt, kp, kd))

        self.torque_command = MessageTemplate(command, [STAMP] + [(f8, nj)] * 6)
        dof, feet = list(robot.dof_names), list(robot.foot_frames)

        def generalized(label):
            return lambda ns, values: GeneralizedForce(header=cv.header_msg(ns, "base"), label=label, names=dof,
                                                       values=np.asarray(values, float).tolist())

        self._generalized = lambda label: MessageTemplate(generalized(label), [STAMP, (f8, nv)])
        self.acceleration = self._generalized("acceleration")
        self.contact_forces = MessageTemplate(
            lambda ns, fx, fy, fz: ContactForces(header=cv.header_msg(ns, "world"), foot_names=feet,
                                                 force_x=np.asarray(fx, float).tolist(),
                                                 force_y=np.asarray(fy, float).tolist(),
                                                 force_z=np.asarray(fz, float).tolist()),
            [STAMP, (f8, nf), (f8, nf), (f8, nf)])
        self.effects = {label: self._generalized(label) for label in effect_labels}

    def live(self, ns: int, m, out) -> list[tuple[str, bytes]]:
        """(topic, CDR) of /clock, /joint_states, /base_state, /contact_state, /torque_command
        for a plant Measurement `m` and a controller output `out` (mode MODE_TORQUE)."""
        return [
            (topics.CLOCK, self.clock.serialize(ns)),
            (topics.JOINT_STATES, self.joint_states.serialize(ns, m.q, m.qd, m.tau_measured)),
            (topics.BASE_STATE, self.base_state.serialize(ns, m.base_position, m.base_orientation,
                                                          m.base_linear_velocity, m.base_angular_velocity)),
            (topics.CONTACT_STATE, self.contact_state.serialize(ns, m.contacts)),
            (topics.TORQUE_COMMAND, self.torque_command.serialize(ns, out.feedforward, out.feedback_linearization,
                                                                  out.q_target, out.qd_target, out.kp, out.kd)),
        ]

    def ground_truth(self, ns: int, truth) -> list[tuple[str, bytes]]:
        """(topic, CDR) of the /sim/ topics of a plant GroundTruth."""
        f = truth.contact_forces
        out = [(topics.SIM_ACCELERATION, self.acceleration.serialize(ns, truth.vdot)),
               (topics.SIM_CONTACT_FORCES, self.contact_forces.serialize(ns, f[:, 0], f[:, 1], f[:, 2]))]
        for label, force in truth.effect_forces.items():
            template = self.effects.get(label)
            if template is None:
                template = self.effects[label] = self._generalized(label)
            out.append((topics.SIM_EFFECT_PREFIX + label, template.serialize(ns, force)))
        return out
