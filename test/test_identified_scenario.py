"""`ciml diagnose` writes identified_scenario.yaml (issue 29 item 2): the identified effects as a ciml_sim
scenario that `ciml record --scenario` loads; with --reference, the reference's effects plus the differences."""
from __future__ import annotations

import json
import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(__file__))
from diag_data import record_plant_bag  # noqa: E402

from ciml_learning.cli.main import main  # noqa: E402
from ciml_learning.core.robot import load_robot  # noqa: E402
from ciml_learning.diagnosis.identified import identified_scenario  # noqa: E402
from ciml_learning.effects import CATALOGUE  # noqa: E402
from ciml_sim.scenario import load_scenario, parse_scenario  # noqa: E402

ROBOT = load_robot()
ONE_OF_EACH = [  # diagnosis.json entries (type, place, params) of every catalogue type
    {"type": "payload", "params": {"mass": 6.0, "com": [0.15, 0.0, 0.05]}},
    {"type": "joint_coulomb_friction", "joint": "lf_kfe_joint", "params": {"value": 5.0}},
    {"type": "joint_viscous_friction", "joint": "lh_hfe_joint", "params": {"value": 4.0}},
    {"type": "actuator_lag", "joints": "all", "params": {"time_constant": 0.01}},
    {"type": "torque_gain", "joint": "rh_hfe_joint", "params": {"value": 0.8}},
    {"type": "torque_offset", "joint": "rh_hfe_joint", "params": {"value": 2.5}},
    {"type": "link_mass_scale", "link": "lf_lowerleg", "params": {"value": 1.4}},
    {"type": "encoder_offset", "joint": "rf_hfe_joint", "params": {"value": 0.02}},
    {"type": "base_imu_tilt", "params": {"roll": 0.01, "pitch": -0.005}},
    {"type": "torque_sensor_gain", "joint": "lh_kfe_joint", "params": {"value": 0.9}},
    {"type": "torque_sensor_offset", "joint": "lh_kfe_joint", "params": {"value": 2.0}},
    {"type": "joint_stribeck_friction", "joint": "rf_kfe_joint",
     "params": {"breakaway": 12.0, "coulomb": 4.0, "velocity": 0.15}},
]


def test_every_catalogue_type_becomes_a_loadable_scenario_entry():
    assert {e["type"] for e in ONE_OF_EACH} == set(CATALOGUE)
    doc = identified_scenario({"effects": ONE_OF_EACH})
    scen = parse_scenario(doc, ROBOT)
    assert [e.type for e in scen.effects] == [e["type"] for e in ONE_OF_EACH]
    for parsed, diag in zip(scen.effects, ONE_OF_EACH):
        assert parsed.params == diag["params"]
    assert scen.effects[3].joints == tuple(range(ROBOT.n_joints)) and scen.effects[6].link == "lf_lowerleg"
    # a value the simulator cannot take is left out and said, never clipped
    far = identified_scenario({"effects": [{"type": "joint_coulomb_friction", "joint": "lf_kfe_joint",
                                            "params": {"value": 150.0}}]})
    assert far["effects"] == [] and "joint_coulomb_friction.value" in far["description"]


def test_with_a_reference_the_reference_effects_plus_the_differences():
    coul = {"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "params": {"value": 6.0}}
    coul_real = {**coul, "params": {"value": 6.1}}
    lag_ref = {"type": "actuator_lag", "joints": "all", "params": {"time_constant": 0.01}}
    gain_real = {"type": "torque_sensor_gain", "joint": "lh_kfe_joint", "params": {"value": 0.85}}
    result = {"effects": [coul_real, gain_real], "reference": {"effects": [coul, lag_ref]},
              "reference_comparison": {"effects": [
                  {"type": "torque_sensor_gain", "where": "lh_kfe_joint", "status": "real only"},
                  {"type": "actuator_lag", "where": "all", "status": "reference only"},
                  {"type": "joint_coulomb_friction", "where": "rf_kfe_joint", "status": "shared"}]}}
    doc = identified_scenario(result)
    assert doc["effects"] == [{"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0},
                              {"type": "torque_sensor_gain", "joint": "lh_kfe_joint", "value": 0.85}]
    result["reference_comparison"]["effects"][2]["status"] = "differs"
    assert identified_scenario(result)["effects"][0]["value"] == 6.1


def test_diagnose_writes_it_and_ciml_record_runs_it(tmp_path):
    scenario = {"name": "t", "seed": 4, "sensor_noise": {"tau": 0.2}, "effects": [
        {"type": "torque_gain", "joint": "rh_hfe_joint", "value": 0.8},
        {"type": "joint_coulomb_friction", "joint": "lf_kfe_joint", "value": 8.0}]}
    bag, out = str(tmp_path / "bag"), str(tmp_path / "diag")
    assert not record_plant_bag(ROBOT, scenario, bag, seconds=9.0, seed=2)["fell"]
    assert main(["diagnose", "--bag", bag, "--out", out]) == 0
    with open(os.path.join(out, "diagnosis.json")) as f:
        effects = json.load(f)["effects"]
    scen = load_scenario(os.path.join(out, "identified_scenario.yaml"), ROBOT)
    assert [e.type for e in scen.effects] == [e["type"] for e in effects] and len(effects) >= 2
    for parsed, diag in zip(scen.effects, effects):
        assert parsed.params == pytest.approx(diag["params"])
    assert main(["record", "--scenario", os.path.join(out, "identified_scenario.yaml"), "--motion", "trot_35",
                 "--duration", "1", "--seed", "1", "--out", str(tmp_path / "resim")]) == 0
