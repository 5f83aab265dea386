"""`ciml diagnose` on small scenario bags with a known answer (recorded from the simulated plant).

- names the right effect, location and parameter of the scenario;
- no /sim/ topic, scenario name or effect list reaches it: the same result on the bag rewritten
  with only the four live topics;
- an effect outside the catalogue ends up mostly unexplained and localised to its leg;
- bad input gives a one-line error and exit 1;
- diagnosis.json holds the docs/ARCHITECTURE.md §6 contract and the model the controller can use.
"""
from __future__ import annotations

import json
import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
from diag_data import copy_topics, record_plant_bag, strip_to_live_topics  # noqa: E402

from ciml_learning.cli.main import main  # noqa: E402
from ciml_learning.core.robot import load_robot  # noqa: E402
from ciml_learning.diagnosis import load_epsilon_function  # noqa: E402
from ciml_learning.diagnosis.run import diagnose  # noqa: E402

ROBOT = load_robot()

SCENARIO = {
    "name": "test_gain_and_friction",
    "seed": 4,
    "sensor_noise": {"tau": 0.2},
    "effects": [
        {"type": "torque_gain", "joint": "rh_hfe_joint", "value": 0.8},
        {"type": "joint_coulomb_friction", "joint": "lf_kfe_joint", "value": 8.0},
    ],
}
OUT_OF_CATALOGUE = {
    "name": "test_spring",
    "seed": 5,
    "sensor_noise": {},
    "effects": [{"type": "joint_spring", "joint": "lh_kfe_joint", "stiffness": 60.0, "rest": 1.0}],
}


@pytest.fixture(scope="module")
def scenario_bag(tmp_path_factory):
    d = tmp_path_factory.mktemp("diag_e2e")
    bag = str(d / "scenario")
    info = record_plant_bag(ROBOT, SCENARIO, bag, seconds=9.0, seed=2)
    assert not info["fell"] and info["ground_truth_topics"]
    return bag


@pytest.fixture(scope="module")
def diagnosis(scenario_bag, tmp_path_factory):
    out = str(tmp_path_factory.mktemp("diag_out") / "diag")
    assert main(["diagnose", "--bag", scenario_bag, "--out", out]) == 0
    with open(os.path.join(out, "diagnosis.json")) as f:
        return out, json.load(f)


def _find(effects, typ, where):
    return [e for e in effects if e["type"] == typ and where in (e.get("joint"), e.get("link"))]


def test_names_the_scenario_effects_locations_and_parameters(diagnosis):
    out, d = diagnosis
    effects = d["effects"]
    gain = _find(effects, "torque_gain", "rh_hfe_joint")
    assert len(gain) == 1 and abs(gain[0]["params"]["value"] - 0.8) / 0.2 < 0.15
    assert gain[0]["std"]["value"] > 0
    fric = _find(effects, "joint_coulomb_friction", "lf_kfe_joint")
    assert len(fric) == 1 and abs(fric[0]["params"]["value"] - 8.0) / 8.0 < 0.2
    # nothing else of consequence
    others = [e for e in effects if e not in gain + fric]
    assert all(e["share"] < 0.05 for e in others), others
    assert gain[0]["share"] + fric[0]["share"] > 0.8
    assert d["shrink"]["ratio"] > 0.6
    # where: the weak actuator is the largest actuation error
    act = [x for x in d["localization"] if x["kind"] == "actuation"]
    assert act[0]["dimension"] == "rh_hfe"


def test_diagnosis_json_contract(diagnosis):
    out, d = diagnosis
    for k in ("localization", "effects", "unexplained_share", "shrink", "data"):
        assert k in d
    shares = [x["share"] for x in d["localization"]]
    assert shares == sorted(shares, reverse=True)
    assert abs(sum(shares) - 1.0) < 1e-6
    for x in d["localization"]:
        assert x["kind"] in ("rbd", "actuation") and x["rms_error"] >= 0
    names = {x["dimension"] for x in d["localization"]}
    assert {"base_roll", "foot_rf_z", "rf_kfe"} <= names and len(names) == 30
    eff_shares = [e["share"] for e in d["effects"]]
    assert eff_shares == sorted(eff_shares, reverse=True)
    assert abs(sum(eff_shares) + d["unexplained_share"] - 1.0) < 1e-6
    s = d["shrink"]
    for k in ("heldout_rms_nominal", "heldout_rms_with_effects", "ratio", "per_dimension"):
        assert k in s
    assert abs(s["ratio"] - (1 - s["heldout_rms_with_effects"] / s["heldout_rms_nominal"])) < 1e-9
    assert "rh_hfe" in s["per_dimension"]
    data = d["data"]
    assert data["samples"] > 0 and data["heldout_samples"] > 0
    assert "last" in data["heldout"]  # a single bag: its last part of time is held out, and it says so
    html = open(os.path.join(out, "report.html"), encoding="utf-8").read()
    assert html.count("data:image/png;base64,") >= 3 and "Where:" in html and "How far:" in html


def test_no_ground_truth_reaches_the_diagnosis(scenario_bag, diagnosis, tmp_path):
    """The same result from the bag rewritten with only the four live sensor topics."""
    from ciml_learning.core import topics
    from ciml_learning.logs import bagio

    live = str(tmp_path / "live_only")
    strip_to_live_topics(scenario_bag, live)
    assert set(bagio.list_topics(live)) == set(topics.SENSOR_TOPICS)
    assert any(t.startswith("/sim/") for t in bagio.list_topics(scenario_bag))
    _, d = diagnosis
    d2 = diagnose(ROBOT, [live], None, None, progress=False)

    def summary(x):
        return [(e["type"], e.get("joint"), e.get("link"), json.dumps(e["params"])) for e in x["effects"]]

    assert summary(d2) == summary(d)
    assert np.isclose(d2["unexplained_share"], d["unexplained_share"], rtol=1e-9)
    assert np.isclose(d2["shrink"]["ratio"], d["shrink"]["ratio"], rtol=1e-9)
    # and the scenario's name appears nowhere in what was read
    assert SCENARIO["name"] not in json.dumps(d2)


def test_epsilon_function_of_the_diagnosis(diagnosis):
    """ε at a reference: the weak actuator's Γ = (1 − 1/g) τ ⇒ ε_j = −(1 − 1/g) τ_ref,j; friction
    ε_j = f_c tanh(q̇_j / v_s); zeros elsewhere in the joints; finite."""
    from types import SimpleNamespace

    import pinocchio as pin

    out, d = diagnosis
    eps_fn = load_epsilon_function(ROBOT, out)
    q = pin.neutral(ROBOT.model)
    q[2] = 0.6
    q[7:] = ROBOT.standing_joints
    v = np.zeros(ROBOT.nv)
    kfe = ROBOT.joint_names.index("lf_kfe_joint")
    v[6 + kfe] = 1.0
    ref = SimpleNamespace(t=0.0, q=q, v=v, a=np.zeros(ROBOT.nv), contacts=np.ones(4, bool))
    eps = eps_fn(ref)
    assert eps.shape == (ROBOT.nv,) and np.all(np.isfinite(eps))
    fric = _find(d["effects"], "joint_coulomb_friction", "lf_kfe_joint")[0]["params"]["value"]
    assert eps[6 + kfe] == pytest.approx(fric * np.tanh(1.0 / d["model"]["coulomb_smoothing"]), rel=1e-6)
    hfe = ROBOT.joint_names.index("rh_hfe_joint")
    assert abs(eps[6 + hfe]) > 1.0  # the weak hip needs more command for the same torque
    quiet = [j for j in range(ROBOT.n_joints) if j not in (kfe, hfe)]
    assert np.allclose(eps[6 + np.array(quiet)], 0.0, atol=0.2)


@pytest.mark.slow
def test_out_of_catalogue_effect_is_unexplained_and_localised(tmp_path):
    bag = str(tmp_path / "spring")
    info = record_plant_bag(ROBOT, OUT_OF_CATALOGUE, bag, seconds=12.0, seed=3)
    assert not info["fell"]
    d = diagnose(ROBOT, [bag], None, None, progress=False)
    assert d["unexplained_share"] > 0.5
    named = [e for e in d["effects"] if e["share"] > 0.3]
    assert not named, named
    # the out-of-catalogue probe finds a joint torque at the spring's joint and measures it
    probe = d["unexplained_localised"][0]
    assert probe["joint"] == "lh_kfe_joint" and probe["share"] > 0.5
    spring = OUT_OF_CATALOGUE["effects"][0]
    assert probe["stiffness"] == pytest.approx(spring["stiffness"], rel=0.15)
    assert probe["torque_at_center"] == pytest.approx(
        -spring["stiffness"] * (probe["position_center"] - spring["rest"]), rel=0.15)
    legs = d["localization_by_leg"]
    assert max(legs, key=legs.get) in ("lh", "base")
    top_leg = [x["dimension"] for x in d["localization"] if not x["dimension"].startswith("base")][:2]
    assert any("lh" in name for name in top_leg), top_leg


def test_bad_input_one_line_error(tmp_path, capsys, scenario_bag):
    from ciml_learning.core import topics

    assert main(["diagnose", "--bag", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not found" in err[0]
    # a bag without the command topic
    partial = str(tmp_path / "no_command")
    copy_topics(scenario_bag, partial, lambda t: t in topics.SENSOR_TOPICS and t != topics.TORQUE_COMMAND)
    assert main(["diagnose", "--bag", partial, "--out", str(tmp_path / "o2")]) == 1
    err = [line for line in capsys.readouterr().err.strip().splitlines() if "error" in line]
    assert len(err) == 1 and "/torque_command" in err[0]
    # --out pointing at a file
    f = tmp_path / "file"
    f.write_text("x")
    assert main(["diagnose", "--bag", scenario_bag, "--out", str(f)]) == 1
    err = capsys.readouterr().err
    assert "not a" in err and "directory" in err


@pytest.mark.slow
def test_command_update_sampling_is_a_baseline_not_an_effect(tmp_path):
    """A log taken at the controller tick before each new command acts (as ciml_sim.recorder writes
    it) carries −½Δu ≈ −(Δt/2)(u̇ + K_p q̇ + K_d q̈) in Φ̃: the baseline absorbs it with the expected
    coefficients, and the nominal scenario gets no effect named."""
    bag = str(tmp_path / "nominal_recorder_timing")
    info = record_plant_bag(ROBOT, {"name": "nominal", "effects": []}, bag, seconds=12.0, seed=6, timing="recorder")
    assert not info["fell"]
    d = diagnose(ROBOT, [bag], None, None, progress=False)
    assert d["effects"] == []
    p = d["baseline"]["params"]
    dt, kp = 1 / 250.0, 800.0  # the generator's tick and joint stiffness
    assert p["udot"] == pytest.approx(-dt / 2, rel=0.3)
    assert p["qd"] == pytest.approx(-kp * dt / 2, rel=0.3)
    b = d["shrink"]["baseline"]
    assert b["heldout_rms_after_baseline"] < 0.5 * b["heldout_rms_before_baseline"]


@pytest.mark.slow
def test_reference_mode_names_only_what_distinguishes_the_logs(scenario_bag, tmp_path, capsys):
    """reference = scenario A (the knee friction), real = A + B (plus the weak hip actuator): the
    comparison names B only, with its parameter; A is shared by both, not a gap between them."""
    ref = str(tmp_path / "reference")
    info = record_plant_bag(ROBOT, {**SCENARIO, "name": "reference", "effects": SCENARIO["effects"][1:]}, ref,
                            seconds=9.0, seed=3)
    assert not info["fell"]
    out = str(tmp_path / "diag")
    assert main(["diagnose", "--bag", scenario_bag, "--reference", ref, "--out", out]) == 0
    assert "Against the reference: torque_gain at rh_hfe_joint (real only" in capsys.readouterr().out
    with open(os.path.join(out, "diagnosis.json")) as f:
        d = json.load(f)
    comp = d["reference_comparison"]
    assert [(x["type"], x["where"], x["status"]) for x in comp["differences"]] == [
        ("torque_gain", "rh_hfe_joint", "real only")]
    diff = comp["differences"][0]
    assert abs(diff["params"]["value"] - 0.8) < 0.05 and diff["std"]["value"] > 0
    shared = {(x["type"], x["where"]) for x in comp["effects"] if x["status"] == "shared"}
    assert ("joint_coulomb_friction", "lf_kfe_joint") in shared
    # both are reported against the nominal model too
    assert {e["type"] for e in d["reference"]["effects"]} >= {"joint_coulomb_friction"}
    assert "torque_gain" not in {e["type"] for e in d["reference"]["effects"]}
