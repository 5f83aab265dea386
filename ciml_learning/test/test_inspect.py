"""`ciml inspect`: topics, rates, stamp problems, role guesses; the draft profile reads the bag."""
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))

from foreign_bags import FEET, UNITREE_ORDER, go1_messages, imu_messages, store, write_bag  # noqa: E402

from ciml_learning.cli.main import main  # noqa: E402
from ciml_learning.core.profile import load_profile, shipped_profile  # noqa: E402
from ciml_learning.logs.inspect_log import inspect_bag  # noqa: E402
from ciml_learning.logs.loginputs import load_log  # noqa: E402


@pytest.fixture(scope="module")
def go1_bag(tmp_path_factory):
    robot = load_profile(shipped_profile("go1")).robot()
    return robot, write_bag(tmp_path_factory.mktemp("i") / "go1", go1_messages(robot, store(), 448.0, 1.0))


def test_inspect_reports_topics_rates_and_roles(go1_bag):
    robot, bag = go1_bag
    rep = inspect_bag(str(bag), robot.joint_names, robot.foot_frames)
    by = {d["topic"]: d for d in rep["topics"]}
    assert by["/joint_states"]["rate_hz"] == pytest.approx(448.0, rel=1e-3)
    assert by["/low_cmd"]["stamps"] == "recording time (no header)"
    roles = rep["roles"]
    assert roles["joint_state"]["spec"]["topic"] == "/joint_states"
    assert roles["base"]["spec"] == {"topic": "/odom", "type": "nav_msgs/msg/Odometry", "twist_frame": "world"}
    assert roles["contacts"]["spec"]["names"] == FEET and 0 < roles["contacts"]["spec"]["threshold"] < 100
    assert roles["command"]["spec"]["fields"]["kp"] == "motor_cmd[*].kp"
    assert rep["extra_joint_entries"] == FEET


def test_draft_profile_loads_the_bag(go1_bag, tmp_path, capsys):
    robot, bag = go1_bag
    out = tmp_path / "draft.yaml"
    assert main(["inspect", "--bag", str(bag), "--out", str(out), "--robot", shipped_profile("go1")]) == 0
    text = capsys.readouterr().out
    assert "/joint_states" in text and "448.0" in text and "draft profile" in text
    prof = load_profile(out)
    assert list(prof.inputs["command"]["joints"]) == UNITREE_ORDER  # taken from the given profile
    log = load_log(prof.robot(), bag, prof)
    assert log.rate_hz == pytest.approx(448.0, rel=1e-3) and len(log) > 400
    # forces 0/100 N: the drafted threshold separates them; the drafted command is the PD law
    assert log.contacts[:, 0].any() and not log.contacts[:, 0].all() and log.contacts[:, 1:].all()
    assert log.u_observed and not any("follows the command" in w for w in log.warnings)


def test_inspect_without_a_robot_and_stamp_problems(tmp_path, capsys):
    robot = load_profile(shipped_profile("go1")).robot()
    msgs = go1_messages(robot, store(), 250.0, 0.4)
    msgs = [m for i, m in enumerate(msgs) if not (m[0] == "/joint_states" and 40 <= i // 4 < 45)]
    bag = write_bag(tmp_path / "gappy", msgs, fmt="sqlite3")
    assert main(["inspect", "--bag", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "1 gaps" in out and "imu" in out
    rep = inspect_bag(str(bag))
    assert rep["roles"]["contacts"]["spec"]["names"] == FEET  # foot-like entries by name
    assert np.isclose(rep["topics"][1]["rate_hz"], 250.0)


def test_drafted_contact_threshold_is_a_share_of_the_weight():
    """The draft threshold is 15 % of the robot's weight (hysteresis 10 %), not the data's midpoint:
    a trot whose stance feet carry half the weight each, with half-sine load profiles (midpoint of
    the readings: ~W/2, which would drop early and late stance)."""
    from ciml_learning.logs.inspect_log import _threshold_from

    mass, g = 13.1, 9.81
    t = np.arange(0.0, 4.0, 0.002)
    phase = (t % 0.5) / 0.5  # a 0.5 s trot cycle: FL+RR stance, then FR+RL
    load = np.pi / 2 * mass * g / 2 * np.abs(np.sin(np.pi * 2 * phase))  # half-sines, mean W/2 per pair
    first = phase < 0.5
    forces = np.stack([np.where(first, load, 0.0), np.where(first, 0.0, load),
                       np.where(first, 0.0, load), np.where(first, load, 0.0)], axis=1)
    assert np.sum(forces, axis=1).mean() == pytest.approx(mass * g, rel=0.01)
    thr, hyst, why = _threshold_from(forces, mass)
    assert (thr, hyst) == (pytest.approx(0.15 * mass * g, abs=1e-3), pytest.approx(0.1 * mass * g, abs=1e-3))
    assert "m g" in why
    thr, hyst, _ = _threshold_from(forces)  # no robot: the readings' own weight
    assert thr == pytest.approx(0.15 * mass * g, rel=0.01) and hyst == pytest.approx(0.1 * mass * g, rel=0.01)
    thr, _, why = _threshold_from(10.0 * forces, mass)  # another unit: the readings' weight, and a warning
    assert thr == pytest.approx(1.5 * mass * g, rel=0.01) and "check the sensor's unit" in why
    assert _threshold_from(np.zeros((10, 4)))[:2] == (0.0, 0.0)


def test_zero_quaternions_and_zero_stamps_are_flagged_and_the_draft_uses_what_works(tmp_path, capsys):
    """An A1-like log: joint states with zero header stamps, an odometry and an IMU whose
    quaternions are zero. Inspect flags them per topic and drafts the fallback — stamp: log, the
    base from the IMU (orientation estimated) and the legs, not the odometry — and the draft reads."""
    robot = load_profile("go1").robot()
    s = store()
    msgs = go1_messages(robot, s, 250.0, 1.0, zero_quat=True, zero_stamps=True, with_command=False)
    bag = write_bag(tmp_path / "a1like", msgs + imu_messages(robot, s, 250.0, 1.0, zero_quat=True))
    rep = inspect_bag(str(bag), robot.joint_names, robot.foot_frames, robot.total_mass)
    problems = {d["topic"]: d["problems"] for d in rep["topics"]}
    assert "250 zero quaternions" in problems["/odom"] and "250 zero quaternions" in problems["/imu"]
    assert any("zero stamps" in p for p in problems["/joint_states"])
    roles = {r: v["spec"] for r, v in rep["roles"].items()}
    assert roles["base"] == {"estimate": "imu_legs"}
    assert roles["imu"]["orientation"] == "estimate" and roles["joint_state"]["stamp"] == "log"
    assert any("/odom has 250 zero quaternions" in n for n in rep["notes"])
    out = tmp_path / "draft.yaml"
    assert main(["--robot", "go1", "inspect", "--bag", str(bag), "--out", str(out)]) == 0
    assert "zero quaternions" in capsys.readouterr().out
    log = load_log(robot, bag, load_profile(str(out)))
    assert "orientation estimated" in log.sources["imu"] and len(log) > 200
