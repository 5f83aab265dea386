"""Reading foreign logs through a robot profile: MCAP, db3, ROS 1; field paths; explaining rejections."""
import copy
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))

from foreign_bags import (  # noqa: E402
    GO1_PROFILE,
    KD,
    KP,
    Q_OFFSET,
    TAU_FF,
    V_WORLD,
    go1_messages,
    go1_signals,
    store,
    write_bag,
)

from ciml_learning.core.profile import profile_from_dict  # noqa: E402
from ciml_learning.logs.bagio import BagError  # noqa: E402
from ciml_learning.logs.loginputs import field_values, load_log  # noqa: E402

PROFILE = profile_from_dict(GO1_PROFILE)
ROBOT = PROFILE.robot()


def _profile(**changes):
    d = copy.deepcopy(GO1_PROFILE)
    for k, v in changes.items():
        if v is None:
            d["inputs"].pop(k)
        else:
            d["inputs"][k] = v
    return profile_from_dict(d)


@pytest.fixture(scope="module")
def go1_mcap(tmp_path_factory):
    return write_bag(tmp_path_factory.mktemp("b") / "go1", go1_messages(ROBOT, store(), 500.0, 1.0))


def test_unitree_like_mcap_is_read_exactly(go1_mcap):
    log = load_log(ROBOT, go1_mcap, PROFILE)
    t, q, qd, tau, force = go1_signals(ROBOT, 500.0, 1.0)
    assert log.rate_hz == pytest.approx(500.0, rel=1e-9)
    assert log.u_observed and len(log) == len(t) - 1  # the first sample has no earlier command
    np.testing.assert_allclose(log.q[:, 7:], q[1:], atol=1e-12)
    np.testing.assert_allclose(log.tau, tau[1:], atol=1e-12)
    # world-frame twist rotated into the base frame (base yawed by 90°): (0.3, 0, 0) → (0, −0.3, 0)
    np.testing.assert_allclose(log.v[:, :3], np.tile([V_WORLD[1], -V_WORLD[0], 0.0], (len(log), 1)), atol=1e-12)
    # PD command of the previous sample, evaluated at this sample (motor order FR, FL, RR, RL → URDF order)
    u = TAU_FF + KP * (q[:-1] + Q_OFFSET - q[1:]) + KD * (0.0 - qd[1:])
    np.testing.assert_allclose(log.u, u, atol=1e-4)  # float32 fields
    np.testing.assert_array_equal(log.contacts, force[1:] > 50.0)
    assert "FL_foot" in log.sources["joint_state"] and not log.warnings  # ignored, listed, no surprise


@pytest.mark.parametrize("fmt", ["sqlite3", "ros1", "ros1 renamed"])
def test_db3_and_ros1_give_the_same_log(tmp_path, go1_mcap, fmt):
    """A ROS 1 bag is one whatever its name: renamed without its .bag suffix it is still read
    (rosbags tells the formats by the suffix; bagio by the file's first bytes)."""
    ros1 = fmt.startswith("ros1")
    path = write_bag(tmp_path / "go1", go1_messages(ROBOT, store(ros1), 500.0, 1.0), fmt=fmt.split()[0], ros1=ros1)
    if fmt == "ros1 renamed":
        path = path.rename(tmp_path / "robot_run_2024")
    a, b = load_log(ROBOT, go1_mcap, PROFILE), load_log(ROBOT, path, PROFILE)
    for f in ("t", "q", "v", "tau", "u", "contacts"):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), atol=1e-9, err_msg=f)


def test_field_paths():
    s = store()
    Mot, Low = s.types["unitree_go/msg/MotorCmd"], s.types["unitree_go/msg/LowCmd"]
    m = Low(level_flag=1, motor_cmd=[Mot(mode=0, q=float(i), dq=0.0, tau=0.0, kp=0.0, kd=0.0) for i in range(20)])
    np.testing.assert_array_equal(field_values(m, "motor_cmd[*].q"), np.arange(20.0))
    assert field_values(m, "motor_cmd[3].q")[0] == 3.0
    with pytest.raises(ValueError, match="no field 'qq'"):
        field_values(m, "motor_cmd[*].qq")


def test_array_and_jointstate_effort_commands(tmp_path):
    s = store()
    msgs = [m for m in go1_messages(ROBOT, s, 250.0, 0.5, with_command=False)]
    JS, F64, Lay = (s.types[x] for x in ("sensor_msgs/msg/JointState", "std_msgs/msg/Float64MultiArray",
                                          "std_msgs/msg/MultiArrayLayout"))
    order = list(reversed(ROBOT.joint_names))
    extra = []
    for topic, _, ns, _ in [m for m in msgs if m[0] == "/joint_states"]:
        extra.append(("/effort_cmd", "std_msgs/msg/Float64MultiArray", ns + 1000,
                      F64(layout=Lay(dim=[], data_offset=0), data=np.arange(12.0)[::-1] * 0.1)))
        extra.append(("/js_cmd", "sensor_msgs/msg/JointState", ns + 1000,
                      JS(header=msgs[0][3].header, name=order, position=np.zeros(0), velocity=np.zeros(0),
                         effort=np.arange(12.0)[::-1] * 0.1)))
    path = write_bag(tmp_path / "b", msgs + extra)
    a = load_log(ROBOT, path, _profile(command={"topic": "/effort_cmd", "type": "std_msgs/msg/Float64MultiArray",
                                                "joints": order}))
    np.testing.assert_allclose(a.u, np.tile(np.arange(12.0) * 0.1, (len(a), 1)))
    # JointState command stamped in the header with the first sample's stamp: held from there
    b = load_log(ROBOT, path, _profile(command={"topic": "/js_cmd", "type": "sensor_msgs/msg/JointState",
                                                "stamp": "log"}))
    np.testing.assert_allclose(b.u, a.u)


def test_no_command_reads_the_rigid_body_part_and_says_so(go1_mcap):
    log = load_log(ROBOT, go1_mcap, _profile(command=None))
    assert not log.u_observed and np.array_equal(log.u, log.tau)
    assert any("not observable" in w for w in log.warnings)


def test_torque_following_the_command_is_flagged(tmp_path):
    path = write_bag(tmp_path / "b", go1_messages(ROBOT, store(), 250.0, 2.0, torque_is_command=True))
    log = load_log(ROBOT, path, PROFILE)
    assert any("follows the command" in w for w in log.warnings), log.warnings
    assert min(log.torque_command_correlation.values()) > 0.99


@pytest.mark.parametrize("case, match", [
    ("zero_quat", r"base \(/odom\): pose.pose.orientation is a zero quaternion"),
    ("zero_stamps", r"joint_state: header.stamp is zero in all 100 messages on /joint_states; "
                    r"set inputs.joint_state.stamp: log"),
])
def test_rejections_name_role_field_and_reason(tmp_path, case, match):
    path = write_bag(tmp_path / "b", go1_messages(ROBOT, store(), 250.0, 0.4, **{case: True}))
    with pytest.raises(BagError, match=match) as err:
        load_log(ROBOT, path, PROFILE)
    assert "\n" not in str(err.value)


def test_missing_joints_missing_topic_and_stale_command_are_explained(tmp_path, go1_mcap):
    d = copy.deepcopy(GO1_PROFILE)
    d["joint_map"] = {"FL_hip_joint": "FR_hip_joint", "FR_hip_joint": "FL_hip_joint"}  # a consistent rename is fine
    load_log(ROBOT, go1_mcap, profile_from_dict(d))
    d["joint_map"] = {"FL_hip_joint": "FL_hip"}
    with pytest.raises(Exception, match="joint_map: targets"):
        profile_from_dict(d).robot()
    with pytest.raises(BagError, match=r"command: bag .* has no messages on /cmd .*remove inputs.command"):
        load_log(ROBOT, go1_mcap, _profile(command={"topic": "/cmd", "type": "std_msgs/msg/Float64MultiArray",
                                                    "joints": list(ROBOT.joint_names)}))
    # joint names the URDF does not know and no map: every missing joint listed
    msgs = go1_messages(ROBOT, store(), 250.0, 0.2)
    for topic, _, _, m in msgs:
        if topic == "/joint_states":
            m.name[:3] = ["a", "b", "c"]
    path = write_bag(tmp_path / "renamed", msgs)
    with pytest.raises(BagError, match=r"joint_state \(/joint_states\): joints \['FL_hip_joint', 'FL_thigh_joint', "
                                       r"'FL_calf_joint'\] of the URDF are missing"):
        load_log(ROBOT, path, PROFILE)
    # a command that stops after 0.1 s: the samples after it are stale (counted, not silently held)
    msgs = [m for m in go1_messages(ROBOT, store(), 250.0, 0.4) if m[0] != "/low_cmd" or m[2] < 1.1e9]
    log = load_log(ROBOT, write_bag(tmp_path / "stale", msgs), PROFILE)
    assert log.rejected["stale_or_missing"] > 60 and log.stamp_report["stale_by_role"]["command"] > 60


def test_native_bag_reads_as_before():
    from ciml_learning.core.robot import load_robot

    bag = os.path.join(os.path.dirname(__file__), "..", "..", "bags", "nominal_stand")
    log = load_log(load_robot(), bag)
    assert log.rate_hz == 250.0 and log.u_observed and log.stamp_report["zero_stamps"] == 0
    assert set(log.sources) == {"joint_state", "base", "contacts", "command"}


def test_estimated_base_and_contacts_are_read_through_the_estimators(tmp_path):
    from foreign_bags import imu_messages

    s = store()
    path = write_bag(tmp_path / "imu", go1_messages(ROBOT, s, 250.0, 1.0) + imu_messages(ROBOT, s, 250.0, 1.0))
    imu = {"topic": "/imu", "type": "sensor_msgs/msg/Imu"}
    a = load_log(ROBOT, path, _profile(imu=imu, base={"estimate": "imu_legs"}))
    assert "estimated" in a.sources["base"] and a.sources["imu"].startswith("topic /imu")
    np.testing.assert_allclose(np.abs(a.q[:, 3:7] @ [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)]), 1.0, atol=1e-9)
    assert np.all(np.isfinite(a.v)) and a.v.shape == (len(a), ROBOT.nv)
    b = load_log(ROBOT, path, _profile(imu=imu, contacts={"estimate": "dynamics"}))
    assert "estimated" in b.sources["contacts"] and b.contacts.shape == (len(b), 4)
    np.testing.assert_allclose(b.v[:, :3], a.v[:, :3] * 0 + [V_WORLD[1], -V_WORLD[0], 0.0], atol=1e-12)  # odometry kept


def test_each_input_topic_reports_its_own_rate(go1_mcap):
    log = load_log(ROBOT, go1_mcap, PROFILE)
    topics = log.stamp_report["topics"]
    assert topics["/low_cmd"]["role"] == "command" and topics["/low_cmd"]["rate_hz"] == pytest.approx(500.0)
    assert set(topics) == {"/joint_states", "/odom", "/foot_force", "/low_cmd"}


def test_a_twist_in_the_pose_frame_read_as_body_twist_is_flagged(go1_mcap, tmp_path):
    s = store()
    msgs = go1_messages(ROBOT, s, 250.0, 0.2)
    for topic, _, _, m in msgs:
        if topic == "/odom":
            m.child_frame_id = "odom"  # child frame = parent frame: the twist is a world-frame one
    log = load_log(ROBOT, write_bag(tmp_path / "b", msgs), _profile(base={"topic": "/odom", "twist_frame": "child"}))
    assert any("twist_frame: world" in w for w in log.warnings)
    assert not any("twist_frame" in w for w in load_log(ROBOT, go1_mcap, PROFILE).warnings)
