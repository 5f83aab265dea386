"""The controller's safe stop (ciml_control.safe_stop) on the simulated robot: a trot whose
reference stops coming lands its swing feet and stands, whatever the gait phase, and a
reference that comes back far ahead is not chased; plain holding of the last pose, the
behaviour before, drops the robot in the same runs."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from ciml_control.controller import IdController
from ciml_control.references import make_reference
from ciml_control.safe_stop import LIVE, STANDING, SafeStop
from ciml_learning.core.profile import load_profile
from ciml_sim.plant import Plant
from ciml_sim.recorder import PHYSICS_STEPS_PER_TICK, SETTLE_TIME, measured_configuration
from ciml_sim.scenario import nominal_scenario

RATE = 250.0
STALL_STARTS = (2.0, 2.12, 2.24, 2.37)  # [s] spread over a trot_35 cycle (both diagonal pairs, touch-down, mid-swing)


def run(robot, mode: str, t_stall: float, stall: float, after: float = 1.5) -> dict:
    """trot_35 on the nominal plant; from t_stall for `stall` s the reference is stale:
    mode "safe_stop" tracks SafeStop, "hold" the last pose with zero velocity (the old law)."""
    plant = Plant(robot, nominal_scenario(), seed=1)
    q_stand = plant.standing_configuration()
    controller, reference = IdController(robot), make_reference(robot, "trot_35", q_stand)
    stop = SafeStop(robot, q_stand)

    def step(ref) -> None:
        m = plant.measure()
        q, v = measured_configuration(m)
        out = controller.compute(q, v, m.contacts, ref)
        plant.set_command(out.feedforward + out.feedback_linearization, out.q_target, out.qd_target, out.kp, out.kd,
                          stamp=m.time)
        plant.step(PHYSICS_STEPS_PER_TICK)

    first = reference.sample(0.0)
    for _ in range(int(SETTLE_TIME * RATE)):
        step(first)
    plant.rewind_clock()
    z_min, state, last, x_stop = math.inf, LIVE, None, 0.0
    for k in range(int((t_stall + stall + after) * RATE)):
        t = k / RATE
        stale = t_stall <= t < t_stall + stall
        if not stale:
            last = reference.sample(t)
        if mode == "safe_stop":
            ref, state = stop.track(last, not stale, t)
        else:
            ref = replace(last, v=0 * last.v, a=0 * last.a) if stale else last
        if t >= t_stall:
            z_min = min(z_min, float(plant.data.qpos[2]))
        if k == int(t_stall * RATE):
            x_stop = float(plant.data.qpos[0])
        step(ref)
    w, x, y, _ = plant.data.qpos[3:7]
    tilt = 2 * math.asin(min(1.0, math.hypot(x, y)))  # angle of the base's z axis from vertical
    return {"z_min": z_min / q_stand[2], "state": state, "tilt": tilt, "contacts": plant.measure().contacts,
            "moved": float(plant.data.qpos[0]) - x_stop, "jump": stop.jump, "qp_failures": controller.qp_failures}


@pytest.mark.parametrize("name", ["hyq", "go1"])
def test_a_stalled_trot_lands_and_stands_at_every_phase(name):
    robot = load_profile(name).robot()
    for t_stall in STALL_STARTS:
        r = run(robot, "safe_stop", t_stall, stall=1.0)  # comes back 35 cm ahead: not chased
        assert r["state"] == STANDING, (t_stall, r)
        assert r["z_min"] > 0.85, (t_stall, r)
        assert r["tilt"] < math.radians(10), (t_stall, r)
        assert np.all(r["contacts"]), (t_stall, r)
        assert r["qp_failures"] == 0, (t_stall, r)


def test_the_old_hold_drops_the_robot_in_the_same_runs():
    """The comparison that makes the test above mean something: HyQ, the last pose held."""
    robot = load_profile("hyq").robot()
    falls = [run(robot, "hold", t, stall=1.0)["z_min"] < 0.5 for t in STALL_STARTS]
    assert sum(falls) >= 3, falls


def test_a_short_stall_resumes_the_gait():
    """A reference back within resume_tolerance (0.03 s at 0.36 m/s: 1.2 cm) is tracked again."""
    robot = load_profile("hyq").robot()
    r = run(robot, "safe_stop", 2.12, stall=0.03, after=2.0)
    assert r["state"] == LIVE, r
    assert r["z_min"] > 0.85, r
    assert r["moved"] > 0.5, r  # 2.1 s of a 0.35 m/s trot
