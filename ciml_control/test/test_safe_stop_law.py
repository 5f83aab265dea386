"""SafeStop's states (ciml_control.safe_stop): live, a stale reference lands the swing feet and
stands, a reference far from the stop or leaping from the one before is not chased."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from ciml_control.references import make_reference, standing_configuration
from ciml_control.safe_stop import LANDING, LIVE, STANDING, SafeStop
from ciml_learning.core.robot import load_robot

ROBOT = load_robot()


def feet(q: np.ndarray) -> np.ndarray:
    data = ROBOT.model.createData()
    pin.framesForwardKinematics(ROBOT.model, data, q)
    return np.array([data.oMf[f].translation for f in ROBOT.foot_frame_ids])


def test_stale_lands_the_swing_feet_straight_down_then_stands_and_resumes_only_nearby():
    q_stand = standing_configuration(ROBOT)
    motion = make_reference(ROBOT, "trot_35", q_stand)
    stop = SafeStop(ROBOT, q_stand)
    t = 2.05
    while np.all(motion.sample(t).contacts):  # a sample with feet in the air
        t += 0.004
    last = motion.sample(t)
    assert stop.track(last, True, 0.0) == (last, LIVE)
    swing = ~last.contacts
    before = feet(last.q)
    mid, state = stop.track(last, False, 0.1)
    assert state == LANDING and np.array_equal(mid.contacts, last.contacts)
    landed, state = stop.track(last, False, 0.35)
    assert state == STANDING and np.all(landed.contacts)
    after = feet(landed.q)
    np.testing.assert_allclose(landed.q[:7], last.q[:7])                  # the base holds
    np.testing.assert_allclose(after[~swing], before[~swing], atol=1e-9)  # stance feet stay
    np.testing.assert_allclose(after[swing, :2], before[swing, :2], atol=1e-9)  # straight down
    np.testing.assert_allclose(after[swing, 2], before[~swing, 2].mean(), atol=1e-9)  # to the ground
    assert np.all(landed.v == 0) and np.all(landed.a == 0)
    # back 0.1 s later: 3.6 cm ahead, not chased; back where it stopped: live again
    _, state = stop.track(motion.sample(t + 0.1), True, 0.4)
    assert state == STANDING and stop.jump > stop.resume_tolerance
    near = motion.sample(t + 0.004)
    assert stop.track(near, True, 0.5) == (near, LIVE)


def test_a_leap_between_fresh_references_stops_the_robot():
    q_stand = standing_configuration(ROBOT)
    motion = make_reference(ROBOT, "trot_35", q_stand)
    stop = SafeStop(ROBOT, q_stand)
    a = motion.sample(2.0)
    assert stop.track(a, True, 0.0)[1] == LIVE
    leap = replace(a, q=a.q + np.r_[0.05, np.zeros(len(a.q) - 1)])
    held, state = stop.track(leap, True, 0.004)
    assert state == LANDING and stop.stopped is a
    np.testing.assert_allclose(held.q[:3], a.q[:3])


def test_a_reference_that_skips_samples_at_its_own_speed_is_no_leap():
    """Lockstep: the simulation waited, the controller's clock moved as far as the reference's."""
    q_stand = standing_configuration(ROBOT)
    motion = make_reference(ROBOT, "trot_35", q_stand)
    stop = SafeStop(ROBOT, q_stand)
    assert stop.track(motion.sample(2.5), True, 2.5)[1] == LIVE
    later = motion.sample(2.59)  # 5 cm further at ~0.5 m/s
    assert stop.track(later, True, 2.59) == (later, LIVE)
    ahead = motion.sample(2.69)  # 0.1 s of motion in 4 ms of the controller's clock: a leap
    assert stop.track(ahead, True, 2.594)[1] == LANDING


def test_a_reference_held_while_fresh_then_caught_up_is_not_a_leap():
    """A reference node late by less than reference_timeout: the controller answers several samples
    with the same (still fresh) reference, then the node catches up with the motion. Its base moved
    over all those samples, which its speed allows: live, not a stop (a stop here left the robot
    standing for the rest of a lockstep run: reference_not_resumed)."""
    q_stand = standing_configuration(ROBOT)
    motion = make_reference(ROBOT, "trot_35", q_stand)
    stop = SafeStop(ROBOT, q_stand)
    t = 2.0
    a = motion.sample(t)
    for k in range(25):  # 0.1 s of samples answered with the same reference
        assert stop.track(a, True, 0.004 * k) == (a, LIVE)
    caught_up = motion.sample(t + 0.1)
    assert np.linalg.norm(caught_up.q[:2] - a.q[:2]) > stop.resume_tolerance  # it does move that far
    assert stop.track(caught_up, True, 0.1) == (caught_up, LIVE)
    # the same jump within one sample of the last new reference is still a leap
    b = motion.sample(t + 0.104)
    assert stop.track(b, True, 0.104)[1] == LIVE
    far = motion.sample(t + 0.204)
    assert stop.track(far, True, 0.108)[1] == LANDING
