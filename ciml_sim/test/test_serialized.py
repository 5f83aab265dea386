"""Fixed-layout CDR templates (ciml_sim.serialized): the same messages as rclpy's, in a few µs."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.robot import load_robot
from ciml_learning.logs.bagio import BagWriter, read_messages
from ciml_sim import recorder
from ciml_sim.plant import Plant
from ciml_sim.scenario import parse_scenario
from ciml_sim.serialized import STAMP, MessageTemplate, SampleSerializer, TemplateError, _serialize

ROBOT = load_robot()
SCENARIO = {"name": "s", "sensor_noise": {"q": 0.001, "tau": 0.3},
            "effects": [{"type": "payload", "mass": 3.0, "com": [0.1, 0.0, 0.0]},
                        {"type": "actuator_lag", "joints": "all", "time_constant": 0.01},
                        {"type": "joint_coulomb_friction", "joint": "all", "value": 1.0}]}


def _sample(seed: int):
    """A plant measurement and ground truth after a few random commands, and a random command."""
    rng = np.random.default_rng(seed)
    plant = Plant(ROBOT, parse_scenario(SCENARIO, ROBOT), seed=seed)
    q0, nj = plant.standing_configuration(), ROBOT.n_joints
    for _ in range(3):
        plant.set_command(rng.normal(0, 20, nj), q0[7:], np.zeros(nj), np.full(nj, 300.0), np.full(nj, 8.0))
        plant.step(4)
    m = plant.measure()
    out = SimpleNamespace(feedforward=rng.normal(0, 50, nj), feedback_linearization=rng.normal(0, 5, nj),
                          q_target=rng.normal(0, 1, nj), qd_target=rng.normal(0, 1, nj),
                          kp=np.full(nj, 300.0), kd=np.full(nj, 8.0))
    return plant, m, out, plant.ground_truth()


def _reference_messages(ns, m, out, truth) -> list[tuple[str, object]]:
    from rosgraph_msgs.msg import Clock

    cmd = cv.TorqueCommandArrays(0, out.feedforward, out.feedback_linearization, out.q_target, out.qd_target,
                                 out.kp, out.kd)
    return [(topics.CLOCK, Clock(clock=cv.stamp_msg(ns))),
            (topics.JOINT_STATES, cv.joint_state_msg(ROBOT, ns, m.q, m.qd, m.tau_measured)),
            (topics.BASE_STATE, cv.odometry_msg(ns, m.base_position, m.base_orientation, m.base_linear_velocity,
                                                m.base_angular_velocity)),
            (topics.CONTACT_STATE, cv.contact_state_msg(ROBOT, ns, m.contacts)),
            (topics.TORQUE_COMMAND, cv.torque_command_msg(ROBOT, ns, cmd))] + \
        recorder.ground_truth_messages(ROBOT, ns, truth)


@pytest.mark.parametrize("seed", [0, 1])
def test_templates_give_rclpys_messages_byte_for_byte_up_to_padding(seed):
    """Every live and /sim/ message of a sample: the template bytes equal rclpy's serialisation
    of the message built the usual way (ciml_learning.core.conversions, recorder.ground_truth_messages)
    with its padding zeroed, and rclpy reads them back to that message."""
    from rclpy.serialization import deserialize_message

    _, m, out, truth = _sample(seed)
    ser = SampleSerializer(ROBOT)
    ns = 123_456_789_012 + seed
    fast = ser.live(ns, m, out) + ser.ground_truth(ns, truth)
    slow = _reference_messages(ns, m, out, truth)
    assert [t for t, _ in fast] == [t for t, _ in slow]
    assert len(fast) == 5 + 2 + len(truth.effect_forces) == 10
    for (topic, data), (_, msg) in zip(fast, slow):
        assert data == _serialize(msg), topic
        back = deserialize_message(data, type(msg))
        assert back == msg, topic


def test_template_refuses_a_message_whose_layout_depends_on_its_values():
    from ciml_msgs.msg import GeneralizedForce

    def build(ns, values):  # the label's length follows the values: no fixed layout
        return GeneralizedForce(header=cv.header_msg(ns), label="x" * (1 + int(abs(values[0])) % 7),
                                names=["a", "b"], values=[float(v) for v in values])

    with pytest.raises(TemplateError):
        MessageTemplate(build, [STAMP, ("<f8", 2)])


def test_stamps_outside_int32_seconds_are_refused():
    from rosgraph_msgs.msg import Clock

    t = MessageTemplate(lambda ns: Clock(clock=cv.stamp_msg(ns)), [STAMP])
    with pytest.raises(TemplateError):
        t.serialize(2**31 * 1_000_000_000)


def test_recorder_writes_the_same_bag_through_templates_and_through_rclpy(tmp_path):
    """_SampleWriter into a BagWriter (templates) and into a writer without write_serialized
    (rclpy messages): the bags hold the same messages."""
    plant, m, out, _ = _sample(3)

    class PlainWriter:  # BagWriter without write_serialized: the rclpy path
        def __init__(self, w):
            self.w = w

        def write(self, topic, ns, msg, msgtype=None):
            self.w.write(topic, ns, msg, msgtype)

    with BagWriter(tmp_path / "fast") as a, BagWriter(tmp_path / "slow") as b:
        fast = recorder._SampleWriter(a, ROBOT, plant, True)
        slow = recorder._SampleWriter(PlainWriter(b), ROBOT, plant, True)
        assert fast.serializer is not None and slow.serializer is None
        fast.write(m, out)
        slow.write(m, out)
        assert a.counts == b.counts and len(a.counts) == 10
    from ciml_learning.logs.bagio import iter_bag_messages, typestore

    store = typestore()
    fast_msgs = list(iter_bag_messages(tmp_path / "fast"))
    slow_msgs = list(iter_bag_messages(tmp_path / "slow"))
    assert [(t, ns, typ) for t, ns, _, typ in fast_msgs] == [(t, ns, typ) for t, ns, _, typ in slow_msgs]
    for (topic, _, fast_raw, typ), (_, _, slow_raw, _) in zip(fast_msgs, slow_msgs):
        # rclpy's bytes with their (unspecified) padding zeroed are the template's bytes
        assert bytes(store.serialize_cdr(store.deserialize_cdr(slow_raw, typ), typ)) == fast_raw, topic
    assert len(read_messages(tmp_path / "fast", [topics.JOINT_STATES])[topics.JOINT_STATES]) == 1
