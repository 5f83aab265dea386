"""Closed loop in the MuJoCo plant (short runs): the controller keeps the robot walking
and trotting on the nominal scenario, without QP failures; the default gap shows up as
more feedback effort."""
import os

import pytest

from ciml_learning.core.robot import load_robot

ROBOT = load_robot()


def _run(scenario: str, motion: str, duration: float):
    from ciml_sim.recorder import run_headless
    from ciml_sim.scenario import load_scenario, scenario_dir

    scen = load_scenario(os.path.join(scenario_dir(), f"{scenario}.yaml"), ROBOT)
    return run_headless(ROBOT, scen, motion, duration, seed=1, progress=False).metrics()


@pytest.mark.slow
@pytest.mark.parametrize("motion,duration", [("trot_35", 4.0), ("walk_30", 6.0)])
def test_nominal_closed_loop_does_not_fall(motion, duration):
    m = _run("nominal", motion, duration)
    assert m["controller"] == "id_controller"
    assert not m["fell"], m
    assert m["qp_failures"] == 0, m
    assert m["duration_s"] == pytest.approx(duration, abs=0.01)
    # it tracks: base within centimetres and a few degrees of the moving reference
    assert m["rms_base_position_error_mm"] < 30.0, m
    assert m["rms_attitude_error_deg"] < 5.0, m


@pytest.mark.slow
def test_gap_scenario_needs_more_feedback():
    nominal = _run("nominal", "trot_35", 3.0)
    gap = _run("default_gap", "trot_35", 3.0)
    assert not gap["fell"] and gap["qp_failures"] == 0, gap
    assert gap["rms_feedback_effort_nm"] > 1.3 * nominal["rms_feedback_effort_nm"], (nominal, gap)
