"""`ciml export-mjcf` (issue 29 item 3): a diagnosis's effects in the user's MJCF, matched by name.

Each exported element reproduces CIML's plant with the same effect: the same torque sequence (20 Nm
sines, no feedback) drives both from the same state, the robot in the air (no contact), for 0.3 s.
Measured (this test's numbers): damping, frictionloss (near-ideal, as the plant's), actuator gain and
bias: identical joint trajectories (0 rad); payload body 3e-11 rad; scaled inertial 4e-5 rad;
actuator lag (filterexact, the exact discretisation, against the plant's backward Euler at 1 ms):
actuator torques within 0.35 Nm, joints within 0.04 rad where the lag itself moves them 0.62 rad.
"""
from __future__ import annotations

import json
import os

import mujoco
import numpy as np
import pytest
import yaml

from ciml_learning.cli.main import main
from ciml_learning.core.robot import load_robot
from ciml_learning.diagnosis.files import write_diagnosis_dir
from ciml_learning.effects.scenario import scenario_effect
from ciml_sim.export_mjcf import export
from ciml_sim.mjcf import build_mjcf, pin_to_mj_state
from ciml_sim.plant import Plant
from ciml_sim.scenario import parse_scenario

ROBOT = load_robot()
# the user's model names its bodies after the URDF links (CIML's own MJCF names them after the joints)
XML = build_mjcf(ROBOT).replace('name="lf_kfe"', 'name="lf_lowerleg"')
EVERY = [
    {"type": "joint_viscous_friction", "joint": "lf_kfe_joint", "params": {"value": 4.0}},
    {"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "params": {"value": 6.0}},
    {"type": "torque_gain", "joint": "lh_hfe_joint", "params": {"value": 0.8}},
    {"type": "torque_offset", "joint": "lh_hfe_joint", "params": {"value": 3.0}},
    {"type": "actuator_lag", "joints": "all", "params": {"time_constant": 0.01}},
    {"type": "payload", "params": {"mass": 6.0, "com": [0.15, 0.0, 0.05]}},
    {"type": "link_mass_scale", "link": "lf_lowerleg", "params": {"value": 1.4}},
    {"type": "encoder_offset", "joint": "rf_hfe_joint", "params": {"value": 0.02}},
    {"type": "base_imu_tilt", "params": {"roll": 0.01, "pitch": -0.005}},
    {"type": "torque_sensor_gain", "joint": "lh_kfe_joint", "params": {"value": 0.9}},
    {"type": "torque_sensor_offset", "joint": "lh_kfe_joint", "params": {"value": 2.0}},
    {"type": "joint_stribeck_friction", "joint": "rh_kfe_joint",
     "params": {"breakaway": 12.0, "coulomb": 4.0, "velocity": 0.15}},
]


def _diagnosis_dir(path: str, effects: list[dict]) -> str:
    write_diagnosis_dir(path, {"effects": effects, "model": {"format_version": 1, "effects": effects}}, None)
    return path


def _compare(effect: dict, steps: int = 300) -> dict:
    """Max differences between CIML's plant with the effect and the patched MJCF, same torques."""
    plant = Plant(ROBOT, parse_scenario({"name": "x", "effects": [scenario_effect(effect)]}, ROBOT))
    nominal = Plant(ROBOT, parse_scenario({"name": "nominal"}, ROBOT))
    q0 = plant.standing_configuration()
    q0[2] += 1.5  # in the air: 0.3 s of free fall, no contact
    plant.reset(q0)
    nominal.reset(q0)
    model = mujoco.MjModel.from_xml_string(export([effect], XML, "model.xml")[0])
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = pin_to_mj_state(q0, np.zeros(ROBOT.nv))
    mujoco.mj_forward(model, data)
    nj = ROBOT.n_joints
    zero = np.zeros(nj)
    out = {"q": 0.0, "torque": 0.0, "effect": 0.0}
    for k in range(steps):
        t = k * model.opt.timestep
        u = 20.0 * np.sin(2 * np.pi * 3.0 * t + np.arange(nj))
        for p in (plant, nominal):
            p.set_command(u, zero, zero, zero, zero, stamp=t)
            p.step(1)
        data.ctrl[:] = u
        mujoco.mj_step(model, data)
        out["q"] = max(out["q"], float(np.max(np.abs(plant.data.qpos[7:] - data.qpos[7:]))))
        out["torque"] = max(out["torque"], float(np.max(np.abs(plant.tau - data.actuator_force))))
        out["effect"] = max(out["effect"], float(np.max(np.abs(plant.data.qpos[7:] - nominal.data.qpos[7:]))))
    return out


@pytest.mark.parametrize("effect", EVERY[:4], ids=lambda e: e["type"])
def test_friction_gain_and_offset_reproduce_the_plant_exactly(effect):
    d = _compare(effect)
    assert d["effect"] > 0.01  # the effect moves the joints: the comparison can fail
    assert d["q"] < 1e-9 and d["torque"] < 1e-9, d


@pytest.mark.parametrize("effect,tol", [(EVERY[5], 1e-8), (EVERY[6], 1e-3)], ids=("payload", "link_mass_scale"))
def test_payload_body_and_scaled_inertial_reproduce_the_plant(effect, tol):
    d = _compare(effect)
    assert d["effect"] > 100 * tol and d["q"] < tol, d


def test_actuator_lag_as_first_order_actuator_dynamics():
    """filterexact (exact discretisation) against the plant's backward Euler: close, not equal."""
    d = _compare(EVERY[4])
    assert d["torque"] < 0.02 * 20.0 and d["q"] < 0.1 * d["effect"], d


def test_export_every_type_compiles_and_sorts_sensors_and_not_exportable(tmp_path, capsys):
    diag = _diagnosis_dir(str(tmp_path / "diag"), EVERY)
    (tmp_path / "model.xml").write_text(XML)
    out = str(tmp_path / "patched.xml")
    assert main(["export-mjcf", "--diagnosis", diag, "--mjcf", str(tmp_path / "model.xml"), "--out", out]) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    model = mujoco.MjModel.from_xml_path(out)
    j = model.joint("lf_kfe_joint").dofadr[0]
    assert model.dof_damping[j] == 4.0 and model.dof_frictionloss[model.joint("rf_kfe_joint").dofadr[0]] == 6.0
    assert model.body("ciml_payload").mass[0] == 6.0
    assert np.all(model.actuator_dyntype == mujoco.mjtDyn.mjDYN_FILTEREXACT)
    assert [x["type"] for x in summary["not_exportable"]] == ["joint_stribeck_friction"]
    with open(summary["sensor_calibration"]) as f:
        sensors = yaml.safe_load(f)["sensors"]
    assert sorted(s["type"] for s in sensors) == sorted(
        ["encoder_offset", "base_imu_tilt", "torque_sensor_gain", "torque_sensor_offset"])


@pytest.mark.parametrize("effects,xml,message", [
    ([{"type": "joint_viscous_friction", "joint": "knee_joint", "params": {"value": 1.0}}], XML,
     'no <joint name="knee_joint">'),
    ([{"type": "link_mass_scale", "link": "lf_upperleg", "params": {"value": 1.2}}], XML,
     'no <body name="lf_upperleg">'),
    ([{"type": "torque_gain", "joint": "lf_haa_joint", "params": {"value": 0.9}}],
     XML.replace('<motor name="lf_haa_joint"', '<position kp="50" name="lf_haa_joint"'), "is a <position>"),
    ([], XML, "identified no effect"),
])
def test_bad_input_is_one_line_and_nothing_is_written(tmp_path, capsys, effects, xml, message):
    diag = _diagnosis_dir(str(tmp_path / "diag"), effects)
    (tmp_path / "model.xml").write_text(xml)
    out = tmp_path / "patched.xml"
    assert main(["export-mjcf", "--diagnosis", diag, "--mjcf", str(tmp_path / "model.xml"), "--out", str(out)]) != 0
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert sorted(os.listdir(tmp_path)) == ["diag", "model.xml"]
