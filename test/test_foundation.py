"""Foundation: install layout, robot description, message round trips (bag and DDS), CLI."""
from __future__ import annotations

import glob
import importlib
import os
import subprocess
import sys
import time
from xml.etree import ElementTree

import numpy as np
import pytest

from ciml_learning.core.robot import load_robot
from ciml_learning.logs import bagio

PACKAGES = ("ciml_learning", "ciml_control", "ciml_sim")
PREFIX = sys.prefix
MSG_TYPES = sorted(os.path.splitext(os.path.basename(p))[0] for p in glob.glob(os.path.join(bagio.msg_dir(), "*.msg")))


def test_ament_index_lists_packages_and_executables():
    index = os.path.join(PREFIX, "share", "ament_index", "resource_index", "packages")
    registered = set(os.listdir(index))
    for pkg in PACKAGES + ("ciml_msgs",):
        assert pkg in registered
        assert os.path.isfile(os.path.join(PREFIX, "share", pkg, "package.xml"))
    from importlib.metadata import distribution

    for pkg in PACKAGES:
        for ep in distribution(pkg).entry_points:
            if ep.group == "console_scripts":
                exe = os.path.join(PREFIX, "lib", pkg, ep.name)
                assert os.access(exe, os.X_OK), exe
                importlib.import_module(ep.module)  # the entry point resolves


def test_hyq_description():
    robot = load_robot()
    assert robot.nv == 18 and robot.nq == 19
    assert robot.joint_names == tuple(f"{leg}_{j}_joint" for leg in ("lf", "lh", "rf", "rh")
                                      for j in ("haa", "hfe", "kfe"))
    assert len(robot.foot_frames) == 4
    urdf_mass = sum(
        float(m.get("value")) for m in ElementTree.parse(robot.urdf_path).getroot().iter("mass")
    )
    assert abs(robot.total_mass - urdf_mass) <= 0.01 * urdf_mass
    # each leg: its 3 joints, and the foot moves only with them
    from ciml_learning.core.dynamics import RigidBodyDynamics

    J = RigidBodyDynamics(robot).foot_jacobians(robot.neutral_configuration())
    for i, leg in enumerate(robot.leg_joints):
        other = [6 + j for j in range(12) if j not in leg]
        assert np.allclose(J[i][:, other], 0.0)


def test_wrong_joint_names_are_rejected():
    from ciml_learning.core.robot import RobotDescriptionError

    robot = load_robot()
    names = list(robot.joint_names)
    perm = robot.joint_permutation(names[::-1])
    assert np.array_equal(np.array(names[::-1])[perm], np.array(names))
    with pytest.raises(RobotDescriptionError, match="missing"):
        robot.joint_permutation(names[:-1] + ["elbow_joint"])
    # remembered per name order (a 250 Hz stream sends the same names), shared read-only
    assert robot.joint_permutation(tuple(names[::-1])) is perm and not perm.flags.writeable
    with pytest.raises(RobotDescriptionError, match="missing"):  # a refused order is refused every time
        robot.joint_permutation(names[:-1] + ["elbow_joint"])
    feet = robot.foot_permutation([f.removesuffix("_foot") for f in robot.foot_frames[::-1]])
    assert list(np.array(robot.foot_frames[::-1])[feet]) == list(robot.foot_frames)


# --- messages --------------------------------------------------------------------------


def _fill(msg, seed: int):
    """Set every field of an rclpy message to a distinct non-default value."""
    rng = np.random.default_rng(seed)
    for name, typ in msg.get_fields_and_field_types().items():
        if typ == "string":
            val = f"{name}_{seed}"
        elif typ in ("double", "float"):
            val = float(rng.normal())
        elif typ == "boolean":
            val = True
        elif typ.startswith(("uint", "int", "octet")):
            val = int(rng.integers(1, 100))
        elif typ == "sequence<double>":
            val = rng.normal(size=3).tolist()
        elif typ == "sequence<string>":
            val = [f"{name}_a", f"{name}_b", f"{name}_c"]
        elif typ == "sequence<boolean>":
            val = [True, False, True]
        elif "/" in typ:
            val = _fill(getattr(msg, name).__class__(), seed + 1)
        else:
            raise AssertionError(f"untested field type {typ}")
        setattr(msg, name, val)
    return msg


def _assert_equal(a, b, path=""):
    """Compare an rclpy message with a rosbags (or rclpy) message field by field."""
    for name in a.get_fields_and_field_types():
        va, vb = getattr(a, name), getattr(b, name)
        if hasattr(va, "get_fields_and_field_types"):
            _assert_equal(va, vb, f"{path}.{name}")
        elif isinstance(va, (str, bool, int, float)):
            assert va == vb, f"{path}.{name}: {va} != {vb}"
        else:
            assert list(va) == list(vb), f"{path}.{name}"


def _msg_class(name):
    return getattr(importlib.import_module("ciml_msgs.msg"), name)


def test_every_ciml_message_round_trips_through_an_mcap_bag(tmp_path):
    assert len(MSG_TYPES) >= 6
    sent = {}
    with bagio.BagWriter(tmp_path / "bag") as writer:
        for i, name in enumerate(MSG_TYPES):
            msg = _fill(_msg_class(name)(), i)
            topic = f"/test/{name}"
            writer.write(topic, 1000 + i, msg, msgtype=f"ciml_msgs/msg/{name}")
            sent[topic] = msg
    received = bagio.read_messages(tmp_path / "bag", sent)
    for topic, msg in sent.items():
        assert len(received[topic]) == 1
        _assert_equal(msg, received[topic][0][1])


@pytest.mark.ros
def test_every_ciml_message_round_trips_over_dds_on_loopback():
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    assert os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] == "LOCALHOST"
    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node("msg_round_trip", context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)
        qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
        received: dict[str, list] = {n: [] for n in MSG_TYPES}
        pubs = {}
        for name in MSG_TYPES:
            cls = _msg_class(name)
            node.create_subscription(cls, f"/test/{name}", lambda m, n=name: received[n].append(m), qos)
            pubs[name] = node.create_publisher(cls, f"/test/{name}", qos)
        sent = {n: _fill(_msg_class(n)(), i) for i, n in enumerate(MSG_TYPES)}
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and not all(received.values()):
            for name, pub in pubs.items():
                if not received[name]:
                    pub.publish(sent[name])
            executor.spin_once(timeout_sec=0.1)
        for name in MSG_TYPES:
            assert received[name], f"{name} not received over DDS"
            _assert_equal(sent[name], received[name][0])
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)


# --- CLI ---------------------------------------------------------------------------------

CIML = os.path.join(PREFIX, "bin", "ciml")


def test_cli_help_lists_every_verb():
    out = subprocess.run([CIML, "--help"], capture_output=True, text=True, check=True).stdout
    for verb in ("record", "extract", "train", "evaluate", "closed-loop", "diagnose", "gap-bench", "play", "bench"):
        assert verb in out


def test_cli_missing_bag_is_a_one_line_error(tmp_path):
    r = subprocess.run([CIML, "extract", "--bag", str(tmp_path / "nope"), "--out", str(tmp_path / "t.npz")],
                       capture_output=True, text=True)
    assert r.returncode != 0
    assert len(r.stderr.strip().splitlines()) == 1
