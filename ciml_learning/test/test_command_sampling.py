"""What the log reader reports about how a log samples its command (stamp_report["command_sampling"]):
the command period, where the samples fall in it, and the share of the command's rate made at the
command updates (the staircase) rather than by the joint loop's feedback between them. The
diagnosis converts an actuator lag's coefficient with it (identification.lag_time_constant)."""
from __future__ import annotations

import numpy as np
import pytest

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.robot import load_robot
from ciml_learning.logs.bagio import BagWriter
from ciml_learning.logs.loginputs import load_log

ROBOT = load_robot()
MS = 1_000_000


def _bag(path, sample_ms: int, offset_ms: int, feedforward: bool, seconds: float = 4.0):
    """A HyQ log in CIML's own topics: joint states every `sample_ms` from `offset_ms` after the first of
    the 250 Hz commands. The commands hold either a moving feed-forward (a staircase; PD gains 0) or a
    fixed target with PD gains on a moving joint (the joint loop's feedback, continuous in time)."""
    nj = ROBOT.n_joints
    q0 = ROBOT.standing_joints
    zero = np.zeros(nj)
    with BagWriter(path) as w:
        for k in range(int(seconds * 250)):
            ns = 4 * MS * k
            s = 20.0 * np.sin(2 * np.pi * 1.3 * ns * 1e-9 + np.arange(nj))
            cmd = cv.TorqueCommandArrays(0, s if feedforward else zero, zero, q0, zero,
                                         zero if feedforward else np.full(nj, 200.0), zero)
            w.write(topics.TORQUE_COMMAND, ns, cv.torque_command_msg(ROBOT, ns, cmd))
        for ns in range(offset_ms * MS, int(seconds * 1e9) - 4 * MS, sample_ms * MS):
            x = 1.3 * 2 * np.pi * ns * 1e-9 + np.arange(nj)
            q = q0 + 0.1 * np.sin(x)
            qd = 0.1 * 1.3 * 2 * np.pi * np.cos(x)
            tau = (20.0 if feedforward else -20.0) * np.sin(x)  # a torque that follows the command's trend
            w.write(topics.JOINT_STATES, ns, cv.joint_state_msg(ROBOT, ns, q, qd, tau))
            w.write(topics.BASE_STATE, ns, cv.odometry_msg(ns, np.array([0, 0, 0.6]), np.array([0, 0, 0, 1.0]),
                                                           np.zeros(3), np.zeros(3)))
            w.write(topics.CONTACT_STATE, ns, cv.contact_state_msg(ROBOT, ns, np.ones(4, dtype=bool)))
    return path


@pytest.mark.parametrize("sample_ms,offset_ms,phases", [(4, 4, [1.0]), (4, 2, [0.5]),
                                                         (1, 1, [0.25, 0.5, 0.75, 1.0])])
def test_phases_in_the_command_period(tmp_path, sample_ms, offset_ms, phases):
    log = load_log(ROBOT, _bag(tmp_path / "b", sample_ms, offset_ms, True))
    cs = log.stamp_report["command_sampling"]
    assert cs["period_s"] == pytest.approx(0.004) and cs["samples"] == len(log)
    assert [p for p, _ in cs["phases"]] == pytest.approx(phases)  # 1.0: on the command instants
    assert [w for _, w in cs["phases"]] == pytest.approx([1 / len(phases)] * len(phases), abs=0.01)


def test_staircase_share_tells_a_held_command_from_the_joint_loops_feedback(tmp_path):
    held = load_log(ROBOT, _bag(tmp_path / "ff", 4, 4, True)).stamp_report["command_sampling"]["staircase_share"]
    fb = load_log(ROBOT, _bag(tmp_path / "pd", 4, 4, False)).stamp_report["command_sampling"]["staircase_share"]
    assert held["all"] == pytest.approx(1.0, abs=0.02) and min(held.values()) > 0.95
    assert fb["all"] == pytest.approx(0.0, abs=0.02) and max(fb.values()) < 0.05
