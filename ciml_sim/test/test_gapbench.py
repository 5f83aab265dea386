"""gap-bench scoring: checked against hand-made diagnoses with a known right answer."""
from __future__ import annotations

import pytest

from ciml_learning.core.robot import load_robot
from ciml_sim import gapbench
from ciml_sim.scenario import CATALOGUE_TYPES, parse_scenario

JOINTS = load_robot().joint_names


def test_every_suite_case_is_a_valid_scenario_and_the_suite_covers_the_catalogue():
    robot = load_robot()
    types = set()
    for i, spec in enumerate(gapbench.SUITE, start=1):
        parse_scenario({"name": f"case_{i:02d}", **gapbench.scenario_of(spec)}, robot)
        if "reference_effects" in spec:
            parse_scenario({"name": f"case_{i:02d}_reference", **gapbench.scenario_of(spec, reference=True)}, robot)
            assert all(e in spec["effects"] for e in spec["reference_effects"])
            assert len(spec["effects"]) > len(spec["reference_effects"])
        types |= {e["type"] for e in spec["effects"]}
    assert len(gapbench.SUITE) >= 16 + 3
    assert set(CATALOGUE_TYPES) <= types  # every catalogue effect, the torque sensor's included
    assert sum(1 for s in gapbench.SUITE if s["effects"][0]["type"] in gapbench.OUT_OF_CATALOGUE) >= 3
    assert any(s["effects"][0]["type"] == "torque_sensor_ripple" for s in gapbench.SUITE)
    assert sum(1 for s in gapbench.SUITE if "reference_effects" in s) >= 2
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
    # localised by the diagnosis' out-of-catalogue probe (unexplained_localised) on that leg, base dims on top
    probe = {**good, "localization": [{"dimension": "base_fz"}],
             "unexplained_localised": [{"joint": "lh_hfe_joint", "share": 0.7},
                                       {"joint": "rf_kfe_joint", "share": 0.1}]}
    o = gapbench.score_case(truth, probe, JOINTS)["out_of_catalogue"]
    assert o["localised_right"] and o["localised_by_probe"] and not o["localised_by_dimension"]
    summary = gapbench.summarise([{"case": 1, **gapbench.score_case(truth, good, JOINTS), "diagnose_s": 1.0}])
    assert summary["out_of_catalogue_unexplained_and_localised"] == 1


def test_coverage_bounds_and_reference_scoring():
    truth = [{"type": "payload", "mass": 6.0, "com": [0.15, 0.0, 0.05]},
             {"type": "actuator_lag", "joints": "all", "time_constant": 0.01}]
    diag = {"effects": [
        {"type": "payload", "params": {"mass": 5.9, "com": [0.14, 0.0, 0.2]},
         "std": {"mass": 0.1, "com": [0.01, 0.01, 0.01]}, "share": 0.6, "confidence": "high"},
        {"type": "actuator_lag", "joints": "all", "params": {"time_constant": 0.0077},
         "std": {"time_constant": 0.0005}, "share": 0.3, "confidence": "high",
         "std_components": {"sampling": {"time_constant": 0.0003}, "conversion": {"time_constant": 0.0004}}}],
        "bounds": {"payload": {"mass": [0.0, 5.0]}}, "shrink": {}, "localization": []}
    s = gapbench.score_case(truth, diag, JOINTS)
    # mass 5.9 ± 0.1 and com x 0.14 ± 0.01 are inside at 95 % only, com y at both, com z and the lag at neither
    assert s["coverage"] == {"in_95": 3, "in_68": 1, "params": 5}
    # the lag's row keeps |error| and each std component (the calibration's which-part question)
    lag = next(r["coverage"] for r in s["effects"] if r["type"] == "actuator_lag")
    assert lag["abs_error"] == [pytest.approx(0.0023)] and lag["error_over_std"] == [pytest.approx(4.6)]
    assert lag["std_components"] == {"sampling": [0.0003], "conversion": [0.0004]}
    assert "std_components" not in next(r["coverage"] for r in s["effects"] if r["type"] == "payload")
    assert s["confident_outside_bounds"] == ["payload:mass=5.9"]
    summary = gapbench.summarise([{"case": 1, **s, "diagnose_s": 1.0}])
    assert summary["coverage_95"] == 0.6 and summary["confident_outside_bounds"] == 1
    # reference case: A shared, B named; a difference in A would be spurious
    a = {"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0}
    b = {"type": "torque_sensor_gain", "joint": "lh_kfe_joint", "value": 0.85}
    comp = {"reference_comparison": {"differences": [
        {"type": "torque_sensor_gain", "where": "lh_kfe_joint", "status": "real only", "params": {"value": 0.86},
         "std": {"value": 0.01}, "share_real": 0.9}]}, "shrink": {}, "localization": []}
    s = gapbench.score_case([a, b], comp, JOINTS, [a])
    assert s["reference"]["named_only_the_difference"] and s["coverage"]["params"] == 1
    comp["reference_comparison"]["differences"].append(
        {"type": "joint_coulomb_friction", "where": "rf_kfe_joint", "status": "differs", "params_real": {"value": 7.0}})
    s = gapbench.score_case([a, b], comp, JOINTS, [a])
    assert not s["reference"]["named_only_the_difference"] and len(s["spurious"]) == 1


def test_resimulated_shrink_is_read_and_summarised(tmp_path):
    """verify.json's overall numbers reach the case and the summary's targets (median of the re-simulated
    shrink over the oracle's, cases where the identified simulator is further than the nominal one)."""
    import json

    from ciml_sim.gapbench import resimulated_scores, summarise

    cases = []
    for i, (gaps, further) in enumerate((((10.0, 1.0, 0.0), False), ((4.0, 5.0, 1.0), True))):
        case = tmp_path / f"case_{i:02d}"
        (case / "verify").mkdir(parents=True)
        nom, ide, ora = gaps
        overall = {"gap_nominal": nom, "gap_identified": ide, "gap_oracle": ora, "shrink": 1 - ide / nom,
                   "shrink_oracle": 1 - ora / nom, "further_than_nominal": further}
        (case / "verify" / "verify.json").write_text(json.dumps({"resimulated_shrink": {"overall": overall}}))
        cases.append({"case": i, "diagnose_s": 1.0, "effects": [], "coverage": {"in_95": 0, "in_68": 0, "params": 0},
                      **resimulated_scores(str(case))})
    assert cases[0]["resim_shrink"] == 0.9 and cases[0]["resim_shrink_oracle"] == 1.0
    assert resimulated_scores(str(tmp_path / "no_case")) == {}
    s = summarise(cases)
    assert s["resimulated_cases"] == 2 and s["cases_identified_further_than_nominal"] == 1
    assert abs(s["median_resimulated_shrink_of_oracle"] - (0.9 + (-0.25 / 0.75)) / 2) < 1e-12


def test_reference_closure_is_the_largest_share_left_and_is_summarised():
    """After re-recording the reference with the identified scenario: the largest share (real or
    reference) of a difference still found; a case is closed at ≤ CLOSURE_SHARE."""
    assert gapbench.reference_closure({"reference_comparison": {"differences": []}}) == 0.0
    left = {"reference_comparison": {"differences": [
        {"type": "link_mass_scale", "where": "lf_hipassembly", "status": "differs", "share_real": 0.005,
         "share_reference": 0.026},
        {"type": "payload", "where": "base", "status": "real only", "share_real": 0.01}]}}
    assert gapbench.reference_closure(left) == 0.026
    cases = [{"case": k, "reference": {"named_only_the_difference": True, "closure_max_share": share},
              "diagnose_s": 1.0} for k, share in ((25, 0.026), (26, 0.2))]
    assert gapbench.summarise(cases)["reference_cases_closed_by_resimulation"] == 1
