"""gap-bench scoring: checked against hand-made diagnoses with a known right answer."""
from __future__ import annotations

import pytest

from ciml_learning.robot import load_robot
from ciml_sim import gapbench
from ciml_sim.scenario import parse_scenario

JOINTS = load_robot().joint_names


def test_every_suite_case_is_a_valid_scenario_and_the_suite_covers_the_catalogue():
    robot = load_robot()
    types = set()
    for i, spec in enumerate(gapbench.SUITE, start=1):
        parse_scenario({"name": f"case_{i:02d}", **spec}, robot)
        types |= {e["type"] for e in spec["effects"]}
    assert len(gapbench.SUITE) >= 16 + 3
    catalogue = {"payload", "link_mass_scale", "joint_coulomb_friction", "joint_viscous_friction", "actuator_lag",
                 "torque_gain", "torque_offset", "encoder_offset", "base_imu_tilt"}
    assert catalogue <= types
    assert sum(1 for s in gapbench.SUITE if s["effects"][0]["type"] in gapbench.OUT_OF_CATALOGUE) >= 3
    assert any(len(s["effects"]) == 3 for s in gapbench.SUITE) and any(len(s["effects"]) == 2 for s in gapbench.SUITE)


def test_right_answer_scores_right():
    truth = [{"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0},
             {"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.85}]
    diag = {"effects": [{"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "params": {"value": 5.4},
                         "share": 0.6},
                        {"type": "torque_gain", "joint": "lf_haa_joint", "params": {"value": 0.88}, "share": 0.3}],
            "unexplained_share": 0.1, "shrink": {"ratio": 0.8}, "localization": []}
    s = gapbench.score_case(truth, diag, JOINTS)
    assert all(r["type_right"] and r["location_right"] for r in s["effects"])
    assert s["effects"][0]["param_rel_error"] == pytest.approx(0.1)
    # a gain is judged on its deviation from 1: 0.12 found for 0.15 true
    assert s["effects"][1]["param_rel_error"] == pytest.approx(0.2)
    assert s["spurious"] == []


def test_wrong_location_and_spurious_effect_are_caught():
    truth = [{"type": "joint_viscous_friction", "joint": "lh_hfe_joint", "value": 4.0}]
    diag = {"effects": [{"type": "joint_viscous_friction", "joint": "rh_hfe_joint", "params": {"value": 4.0},
                         "share": 0.7},
                        {"type": "payload", "params": {"mass": 1.0, "com": [0, 0, 0]}, "share": 0.2}],
            "unexplained_share": 0.1, "shrink": {"ratio": 0.7}, "localization": []}
    s = gapbench.score_case(truth, diag, JOINTS)
    assert s["effects"][0]["type_right"] and not s["effects"][0]["location_right"]
    assert {e["type"] for e in s["spurious"]} == {"joint_viscous_friction", "payload"}


def test_lag_on_all_joints_found_per_joint_counts():
    truth = [{"type": "actuator_lag", "joints": "all", "time_constant": 0.012}]
    found = [{"type": "actuator_lag", "joint": j, "params": {"time_constant": 0.011}, "share": 0.08} for j in JOINTS]
    s = gapbench.score_case(truth, {"effects": found, "shrink": {}, "localization": []}, JOINTS)
    assert s["effects"][0]["location_right"]
    assert s["effects"][0]["param_rel_error"] == pytest.approx(1 / 12)
    few = found[:3]
    s = gapbench.score_case(truth, {"effects": few, "shrink": {}, "localization": []}, JOINTS)
    assert not s["effects"][0]["location_right"]


def test_out_of_catalogue_scoring():
    truth = [{"type": "joint_spring", "joint": "lh_hfe_joint", "stiffness": 80.0, "rest": 0.0}]
    good = {"effects": [], "unexplained_share": 0.8, "shrink": {"ratio": 0.05},
            "localization": [{"dimension": "foot_lh_z"}, {"dimension": "base_pitch"}]}
    o = gapbench.score_case(truth, good, JOINTS)["out_of_catalogue"]
    assert o["unexplained_large"] and o["localised_right"] and not o["named_wrong_with_confidence"]
    bad = {"effects": [{"type": "encoder_offset", "joint": "lh_hfe_joint", "share": 0.7}], "unexplained_share": 0.2,
           "shrink": {"ratio": 0.6}, "localization": [{"dimension": "foot_rf_z"}]}
    o = gapbench.score_case(truth, bad, JOINTS)["out_of_catalogue"]
    assert not o["unexplained_large"] and not o["localised_right"] and o["named_wrong_with_confidence"]
    summary = gapbench.summarise([{"case": 1, **gapbench.score_case(truth, good, JOINTS), "diagnose_s": 1.0}])
    assert summary["out_of_catalogue_unexplained_and_localised"] == 1
