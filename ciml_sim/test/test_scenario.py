"""Scenario files: validated on load, one-line errors naming the field and the valid choices."""
from __future__ import annotations

import pytest

from ciml_learning.core.robot import load_robot
from ciml_sim.scenario import (
    CATALOGUE_TYPES,
    EFFECT_TYPES,
    ScenarioError,
    load_scenario,
    parse_scenario,
    resolve_scenario,
    shipped_scenarios,
)

ROBOT = load_robot()
VALID = {
    "payload": {"mass": 6.0, "com": [0.15, 0.0, 0.05]},
    "joint_coulomb_friction": {"joint": "rf_kfe_joint", "value": 6.0},
    "joint_viscous_friction": {"joint": "lh_hfe_joint", "value": 4.0},
    "actuator_lag": {"joints": "all", "time_constant": 0.012},
    "torque_gain": {"joint": "lf_haa_joint", "value": 0.85},
    "torque_offset": {"joint": "rh_kfe_joint", "value": 3.0},
    "link_mass_scale": {"link": "lf_lowerleg", "value": 1.4},
    "encoder_offset": {"joint": "rf_hfe_joint", "value": 0.02},
    "base_imu_tilt": {"roll": 0.01, "pitch": -0.005},
    "joint_stribeck_friction": {"joint": "rf_kfe_joint", "breakaway": 8.0, "coulomb": 4.0, "velocity": 0.1},
    "joint_spring": {"joint": "lf_kfe_joint", "stiffness": 20.0, "rest": -1.4},
    "torque_ripple": {"joint": "rh_hfe_joint", "amplitude": 2.0, "period": 0.5},
    "torque_sensor_gain": {"joint": "lh_kfe_joint", "value": 0.9},
    "torque_sensor_offset": {"joint": "lh_haa_joint", "value": 2.0},
    "torque_sensor_ripple": {"joint": "lf_kfe_joint", "amplitude": 6.0, "period": 0.628},
}


def _error(data) -> str:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(data, ROBOT)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def _one(effect: dict) -> dict:
    return {"name": "t", "effects": [effect]}


def test_every_effect_type_parses_and_design_example_loads(tmp_path):
    assert set(VALID) == set(EFFECT_TYPES) and len(CATALOGUE_TYPES) == 12  # Stribeck friction joined it
    scen = parse_scenario({"name": "all", "seed": 3, "sensor_noise": {"q": 0.0005, "tau": 0.5},
                           "effects": [{"type": t, **p} for t, p in VALID.items()]}, ROBOT)
    assert [e.type for e in scen.effects] == list(VALID)
    assert scen.effects[3].joints == tuple(range(12))
    assert scen.effects[1].joints == (ROBOT.joint_names.index("rf_kfe_joint"),)
    assert scen.effects[6].link == "lf_lowerleg"
    assert len({e.label for e in scen.effects}) == len(scen.effects)
    for name in ("nominal", "default_gap"):
        assert name in shipped_scenarios()
        assert resolve_scenario(name, ROBOT).name == name
    assert resolve_scenario("nominal", ROBOT).effects == ()
    path = tmp_path / "s.yaml"
    path.write_text("name: x\neffects:\n  - {type: torque_gain, joint: [lf_haa_joint, rf_haa_joint], value: 0.9}\n")
    s = load_scenario(path, ROBOT)
    assert s.effects[0].label == "torque_gain_lf_haa_rf_haa"


def test_labels_are_unique_and_topic_safe():
    s = parse_scenario({"name": "t", "effects": [
        {"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.9},
        {"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.8},
        {"type": "payload", "mass": 1.0, "com": [0, 0, 0]}]}, ROBOT)
    assert [e.label for e in s.effects] == ["torque_gain_lf_haa", "torque_gain_lf_haa_2", "payload"]


def test_unknown_type_names_the_valid_types():
    msg = _error(_one({"type": "joint_backlash", "joint": "rf_kfe_joint", "value": 1.0}))
    assert "effects[0].type" in msg and "joint_backlash" in msg
    assert all(t in msg for t in EFFECT_TYPES)


def test_unknown_joint_names_the_valid_joints():
    msg = _error(_one({"type": "joint_coulomb_friction", "joint": "rf_knee", "value": 6.0}))
    assert "effects[0].joint" in msg and "rf_knee" in msg
    assert "rf_kfe_joint" in msg and "all" in msg


def test_unknown_link_names_the_valid_links():
    msg = _error(_one({"type": "link_mass_scale", "link": "lf_shin", "value": 1.2}))
    assert "effects[0].link" in msg and "lf_shin" in msg and "lf_lowerleg" in msg


@pytest.mark.parametrize("effect, field", [
    ({"type": "torque_gain", "joint": "lf_haa_joint", "value": 3.0}, "effects[0].value"),
    ({"type": "torque_gain", "joint": "lf_haa_joint", "value": float("nan")}, "effects[0].value"),
    ({"type": "torque_gain", "joint": "lf_haa_joint", "value": True}, "effects[0].value"),
    ({"type": "torque_gain", "joint": "lf_haa_joint", "value": "0.9"}, "effects[0].value"),
    ({"type": "actuator_lag", "joints": "all", "time_constant": -0.01}, "effects[0].time_constant"),
    ({"type": "payload", "mass": 6.0, "com": [0.15, 0.0]}, "effects[0].com"),
    ({"type": "payload", "mass": 6.0, "com": [0.15, 0.0, 5.0]}, "effects[0].com[2]"),
    ({"type": "joint_stribeck_friction", "joint": "rf_kfe_joint", "breakaway": 1.0, "coulomb": 4.0, "velocity": 0.1},
     "effects[0].breakaway"),
])
def test_out_of_range_or_malformed_value_names_the_field_and_the_range(effect, field):
    msg = _error(_one(effect))
    assert msg.startswith(field)


def test_missing_and_extra_fields_are_named():
    msg = _error(_one({"type": "torque_gain", "joint": "lf_haa_joint"}))
    assert "missing" in msg and "value" in msg
    msg = _error(_one({"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.9, "gain": 1}))
    assert "unknown" in msg and "gain" in msg and "value" in msg


def test_top_level_and_noise_errors():
    assert "valid:" in _error({"name": "x", "efects": []})
    assert "sensor_noise.q_dot" in _error({"name": "x", "sensor_noise": {"q_dot": 0.1}})
    assert "sensor_noise.q" in _error({"name": "x", "sensor_noise": {"q": -1.0}})
    assert _error({"name": "x", "effects": {"type": "payload"}}).startswith("effects:")
    assert _error({"name": "x", "seed": 1.5}).startswith("seed:")
    assert _error(["not", "a", "mapping"]).startswith("scenario:")


def test_file_errors_are_one_line(tmp_path):
    with pytest.raises(ScenarioError, match="not found"):
        load_scenario(tmp_path / "missing.yaml", ROBOT)
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ScenarioError) as info:
        load_scenario(bad, ROBOT)
    assert "invalid YAML" in str(info.value) and "\n" not in str(info.value)
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text("name: w\neffects:\n  - {type: torque_gain, joint: knee, value: 0.9}\n")
    with pytest.raises(ScenarioError, match=r"wrong.yaml: effects\[0\].joint: unknown joint 'knee'"):
        load_scenario(wrong, ROBOT)
    with pytest.raises(ScenarioError, match="shipped scenario: .*default_gap"):
        resolve_scenario("no_such_scenario", ROBOT)
