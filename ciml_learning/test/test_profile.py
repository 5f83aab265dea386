"""The robot profile loader: shipped profiles load; every error is one line naming the key."""
import copy

import pytest

from ciml_learning.core.profile import ProfileError, load_profile, profile_from_dict, shipped_profile

BASE = {"format": 1, "name": "t", "urdf": "erd:go1_description/urdf/go1.urdf",
        "feet": ["FL_foot", "FR_foot", "RL_foot", "RR_foot"],
        "inputs": {"joint_state": {"topic": "/joint_states"},
                   "base": {"topic": "/odom"},
                   "contacts": {"estimate": "dynamics"}}}


@pytest.mark.parametrize("name, joints, limit", [("hyq", "lf_haa_joint", 150.0), ("go1", "FL_hip_joint", 23.7),
                                                  ("solo12", "FL_HAA", 2.7)])
def test_shipped_profiles_build_their_robot(name, joints, limit):
    prof = load_profile(shipped_profile(name))
    robot = prof.robot()
    assert robot.n_joints == 12 and robot.n_feet == 4 and joints in robot.joint_names
    assert robot.torque_limits[robot.joint_names.index(joints)] == pytest.approx(limit)


def test_default_is_hyq_with_ciml_topics():
    prof = load_profile()
    assert prof.name == "hyq" and prof.inputs["command"]["type"] == "ciml_msgs/msg/TorqueCommand"
    assert prof.inputs["base"]["twist_frame"] == "child"


def _set(path, value):
    d = copy.deepcopy(BASE)
    node = d
    *head, last = path.split(".")
    for k in head:
        node = node.setdefault(k, {})
    if value is KeyError:
        node.pop(last)
    else:
        node[last] = value
    return d


@pytest.mark.parametrize("path, value, match", [
    ("format", 2, "format: must be 1"),
    ("urdf", "nope.urdf", "urdf: file not found"),
    ("feet", "FL_foot,FL_foot", "feet: names repeat"),
    ("torque_source", "amps", "torque_source: must be one of sensor, current_estimate, none"),
    ("torque_limits", {"FL_hip_joint": -1}, r"torque_limits.FL_hip_joint: must be > 0"),
    ("inputs.joint_state", KeyError, "inputs.joint_state: missing"),
    ("inputs.base.twist_frame", "body", "inputs.base.twist_frame: must be one of child, world, got 'body'"),
    ("inputs.base", {"estimate": "imu_legs"}, "inputs.base: estimate: imu_legs needs inputs.imu"),
    ("inputs.contacts", {"topic": "/f", "type": "std_msgs/msg/Float64MultiArray"}, "inputs.contacts.field: missing"),
    ("inputs.contacts", {"topic": "/f", "type": "std_msgs/msg/Float64MultiArray", "field": "data", "hysteresis": 2},
     "inputs.contacts.hysteresis: given without a threshold"),
    ("inputs.command", {"topic": "/c", "type": "std_msgs/msg/Float64MultiArray"}, "inputs.command.joints: must be"),
    ("inputs.command", {"topic": "/c", "type": "x/msg/LowCmd", "joints": ["a"], "fields": {"q_des": "m[*].q"}},
     r"inputs.command.fields: missing \['kp'\]"),
    ("inputs.odometry", {}, "inputs: unknown keys \\['odometry'\\]"),
    ("colour", "red", "top level: unknown keys \\['colour'\\]"),
])
def test_errors_name_the_key(path, value, match):
    with pytest.raises(ProfileError, match=match) as err:
        profile_from_dict(_set(path, value), "profile t.yaml")
    assert "\n" not in str(err.value) and str(err.value).startswith("profile t.yaml: ")


def test_robot_level_errors(tmp_path):
    with pytest.raises(ProfileError, match=r"torque_limits: joints \['knee'\] are not in the URDF"):
        profile_from_dict(_set("torque_limits", {"knee": 3.0})).robot()
    p = tmp_path / "bad.yaml"
    p.write_text("format: 1\nname: [unclosed\n")
    with pytest.raises(ProfileError, match="not valid YAML"):
        load_profile(p)


def test_relative_urdf_and_ros1_type_names(tmp_path):
    import shutil

    from ciml_learning.core.robot import example_robot_data_dir

    src = f"{example_robot_data_dir()}/go1_description/urdf/go1.urdf"
    shutil.copy(src, tmp_path / "go1.urdf")
    d = _set("urdf", "go1.urdf")
    d["inputs"]["base"] = {"topic": "/odom", "type": "nav_msgs/Odometry"}
    import yaml

    (tmp_path / "p.yaml").write_text(yaml.safe_dump(d))
    prof = load_profile(tmp_path / "p.yaml")
    assert prof.urdf == str(tmp_path / "go1.urdf") and prof.inputs["base"]["type"] == "nav_msgs/msg/Odometry"
