"""Headless recording: the bag has the live graph's topics at 250 Hz, ground truth only
under /sim/, nothing else that reveals the scenario; `ciml record` / `ciml closed-loop`."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from ciml_learning.core import topics
from ciml_learning.core.robot import load_robot
from ciml_learning.logs import bagio
from ciml_learning.logs.bagio import BagWriter, list_topics, read_messages
from ciml_learning.logs.loginputs import load_log
from ciml_sim import recorder
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import EFFECT_TYPES, parse_scenario, resolve_scenario

ROBOT = load_robot()
CIML = os.path.join(sys.prefix, "bin", "ciml")
LIVE = {topics.JOINT_STATES, topics.BASE_STATE, topics.CONTACT_STATE, topics.TORQUE_COMMAND, topics.CLOCK}
ACTUATOR_ONLY = {"name": "secret_actuators_scenario", "effects": [
    {"type": "actuator_lag", "joints": "all", "time_constant": 0.01},
    {"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.85},
    {"type": "torque_offset", "joint": "rh_kfe_joint", "value": 2.0},
    {"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 3.0},
    {"type": "encoder_offset", "joint": "rf_hfe_joint", "value": 0.01}]}


def _stamps(msgs) -> np.ndarray:
    return np.array([s for s, _ in msgs], dtype=np.int64)


def test_recorded_bag_has_the_live_topics_at_250_hz_and_ground_truth_under_sim(tmp_path):
    scen = parse_scenario(ACTUATOR_ONLY, ROBOT)
    path = tmp_path / "bag"
    with BagWriter(path) as w:
        result = run_headless(ROBOT, scen, "base_only", 1.2, seed=0, writer=w, progress=False)
    assert not result.fell and result.controller == "id_controller"
    found = list_topics(path)
    truth = {topics.SIM_ACCELERATION, topics.SIM_CONTACT_FORCES} | {
        topics.SIM_EFFECT_PREFIX + e.label for e in scen.effects if e.type != "encoder_offset"}
    assert set(found) == LIVE | truth
    assert all(found[t] == topics.topic_type(t) for t in found)
    msgs = read_messages(path, found)
    n = int(round(1.2 * 250))
    for t in found:
        assert len(msgs[t]) == n, t
        s = _stamps(msgs[t])
        assert s[0] == 0 and np.all(np.diff(s) == 4_000_000), t  # 250 Hz of simulation time
    clock = [m.clock.sec * 10**9 + m.clock.nanosec for _, m in msgs[topics.CLOCK]]
    assert np.array_equal(clock, _stamps(msgs[topics.JOINT_STATES]))
    # the bag's measured torque minus the command the bag pairs with it (Γ, eq. 14) is exactly
    # the sum of the actuator effects' ground truth: sensors, commands and truth line up in time
    log = load_log(ROBOT, path)
    assert len(log) == n - 1  # the first sample has no command before it
    gamma = log.tau - log.u
    act = sum(np.array([m.values for _, m in msgs[topics.SIM_EFFECT_PREFIX + e.label]])
              for e in scen.effects if e.type in ("actuator_lag", "torque_gain", "torque_offset"))
    np.testing.assert_allclose(gamma, act[1:, 6:], atol=1e-9)
    assert np.abs(gamma).max() > 1.0
    # ground truth names and frames
    _, acc = msgs[topics.SIM_ACCELERATION][0]
    assert list(acc.names) == list(ROBOT.dof_names)
    _, cf = msgs[topics.SIM_CONTACT_FORCES][-1]
    assert list(cf.foot_names) == list(ROBOT.foot_frames)
    assert sum(cf.force_z) > 0.5 * ROBOT.total_mass * 9.81


def test_ground_truth_does_not_change_the_recorded_sensors(tmp_path):
    """Reading the ground truth does not disturb the simulation: bit-identical at the plant
    level; through the QP controller equal to 1e-6 (proxsuite differs at ~1e-12 between runs)."""
    from ciml_control.standing import StandingController
    from ciml_sim.plant import Plant

    scen = resolve_scenario("default_gap", ROBOT)

    def plant_run(gt: bool) -> np.ndarray:
        plant, ctl = Plant(ROBOT, scen, seed=3), StandingController(ROBOT)
        q0, rows = plant.standing_configuration(), []
        for _ in range(100):
            m = plant.measure()
            if gt:
                plant.ground_truth()
            rows.append(np.r_[m.q, m.qd, m.tau_measured, m.base_orientation, m.base_linear_velocity, m.contacts])
            c = ctl.compute(q0, m.contacts)
            plant.set_command(c.feedforward, c.q_target, c.qd_target, c.kp, c.kd)
            plant.step(4)
        return np.array(rows)

    assert np.array_equal(plant_run(True), plant_run(False))
    for name, gt in (("with", True), ("without", False)):
        with BagWriter(tmp_path / name) as w:
            run_headless(ROBOT, scen, "stand", 0.4, seed=3, writer=w, ground_truth=gt, progress=False)
    a = load_log(ROBOT, tmp_path / "with")
    b = load_log(ROBOT, tmp_path / "without")
    for f in ("t", "q", "v", "tau", "u", "contacts"):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=1e-6, atol=1e-6, err_msg=f)
    assert not any(topics.is_ground_truth(t) for t in list_topics(tmp_path / "without"))


def _secrets(scen) -> list[bytes]:
    words = {scen.name, "secret", "scenario"} | set(EFFECT_TYPES) | {e.label for e in scen.effects}
    return [w.encode() for w in words]


def _files(path) -> list[tuple[str, bytes]]:
    return [(f, open(os.path.join(root, f), "rb").read()) for root, _, files in os.walk(path) for f in files]


def test_bag_without_ground_truth_reveals_nothing_of_the_scenario(tmp_path):
    # uncompressed (BagWriter as is): grep every byte of every file of the bag
    scen = parse_scenario(ACTUATOR_ONLY, ROBOT)
    with BagWriter(tmp_path / "plain") as w:
        run_headless(ROBOT, scen, "stand", 0.3, seed=0, writer=w, ground_truth=False, progress=False)
    assert set(list_topics(tmp_path / "plain")) == LIVE
    for name, data in _files(tmp_path / "plain"):
        for secret in _secrets(scen):
            assert secret not in data, (name, secret)
    # `ciml record` (zstd-compressed chunks): metadata and every message payload
    yaml_path = tmp_path / "secret_actuators_scenario.yaml"
    import yaml

    yaml_path.write_text(yaml.safe_dump(ACTUATOR_ONLY))
    out = tmp_path / "cli_bag"
    r = subprocess.run([CIML, "record", "--scenario", str(yaml_path), "--motion", "stand", "--duration", "0.3",
                        "--seed", "2", "--out", str(out), "--no-ground-truth"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.strip().splitlines()[-1])["samples"] == 75
    assert set(list_topics(out)) == LIVE
    blobs = [data for _, data in _files(out) if _.endswith(".yaml")]
    blobs += [raw for _, _, raw, _ in bagio.iter_bag_messages(out)]
    from rosbags.highlevel import AnyReader

    with AnyReader([out], default_typestore=bagio.typestore()) as reader:
        blobs += [c.msgdef.data.encode() for c in reader.connections]
    for data in blobs:
        for secret in _secrets(scen):
            assert secret not in data, secret
    assert sum(os.path.getsize(os.path.join(out, f)) for f in os.listdir(out)) < 150_000  # compressed


def test_cli_errors_are_one_line_and_exit_1(tmp_path):
    cases = [
        ["record", "--scenario", "nope", "--motion", "stand", "--out", str(tmp_path / "a")],
        ["record", "--scenario", "nominal", "--motion", "moonwalk", "--out", str(tmp_path / "a")],
        ["record", "--scenario", "nominal", "--motion", "stand", "--duration", "nan", "--out", str(tmp_path / "a")],
        ["closed-loop", "--scenario", "nominal", "--motion", "stand", "--model", str(tmp_path / "missing"),
         "--out", str(tmp_path / "r.json")],
        ["closed-loop", "--scenario", "nominal", "--motion", "stand", "--model", str(tmp_path / "empty"),
         "--out", str(tmp_path / "r.json")],
    ]
    (tmp_path / "empty").mkdir()
    for args in cases:
        r = subprocess.run([CIML, *args], capture_output=True, text=True, timeout=120)
        assert r.returncode == 1, (args, r.stderr)
        lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
        assert len(lines) == 1 and lines[0].startswith(f"ciml {args[0]}: error:"), r.stderr
    assert not (tmp_path / "a").exists() and not (tmp_path / "r.json").exists()


def test_closed_loop_writes_the_paper_metrics(tmp_path):
    out = tmp_path / "result.json"
    r = subprocess.run([CIML, "closed-loop", "--scenario", "default_gap", "--motion", "stand", "--model", "nominal",
                        "--duration", "1", "--out", str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    doc = json.loads(out.read_text())
    m = doc["metrics"]
    for key in ("rms_feedback_effort_nm", "rms_attitude_error_deg", "rms_base_position_error_mm",
                "rms_joint_error_deg", "qp_failures", "fell"):
        assert key in m
    assert m["fell"] is False and m["samples"] == 250 and 0 < m["rms_feedback_effort_nm"] < 100
    assert doc["model"] == "nominal" and doc["motion"] == "stand"


def test_epsilon_function_is_used_by_the_controller(monkeypatch):
    """A model error that cancels the default gap's payload lowers the feedback effort."""
    scen = parse_scenario({"name": "p", "effects": [{"type": "payload", "mass": 10.0, "com": [0.2, 0.0, 0.0]}]}, ROBOT)
    from ciml_sim.plant import Plant

    plant = Plant(ROBOT, scen)
    import pinocchio as pin

    def eps(ref):  # ε = (rnea_true − rnea_nominal) at the reference: the payload's missing force
        return (pin.rnea(plant.true_model, plant.true_model.createData(), ref.q, ref.v, ref.a)
                - pin.rnea(ROBOT.model, ROBOT.model.createData(), ref.q, ref.v, ref.a))

    nominal = run_headless(ROBOT, scen, "stand", 1.0, seed=0, progress=False).metrics()
    informed = run_headless(ROBOT, scen, "stand", 1.0, seed=0, epsilon_fn=eps, progress=False).metrics()
    assert informed["rms_feedback_effort_nm"] < 0.7 * nominal["rms_feedback_effort_nm"]
    assert informed["rms_base_position_error_mm"] < nominal["rms_base_position_error_mm"]


ALL_SENSORS = {"name": "s", "sensor_noise": {"q": 0.0005, "qd": 0.01, "tau": 0.5, "base_orientation": 0.001,
                                              "base_position": 0.001, "base_velocity": 0.01},
               "effects": ACTUATOR_ONLY["effects"] + [{"type": "base_imu_tilt", "roll": 0.01, "pitch": -0.005},
                                                      {"type": "payload", "mass": 6.0, "com": [0.15, 0.0, 0.05]}]}


def _same_runs(a, b) -> None:
    assert (a.fell, a.fall_time, a.qp_failures, len(a.t)) == (b.fell, b.fall_time, b.qp_failures, len(b.t))
    for f in ("t", "feedback_effort", "attitude_error", "base_position_error", "joint_error"):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=1e-9, atol=1e-12, err_msg=f)


@pytest.mark.parametrize("scenario", ["default_gap", "all_sensors"])
def test_compiled_closed_loop_runs_the_step_by_step_ticks(scenario):
    """The compiled closed loop (nominal model, no bag) gives the run of the step-by-step
    ticks (forced by a model error of zeros), noise streams included: 1.2 s crosses a
    noise block, which the compiled loop hands back to a Python tick."""
    scen = (parse_scenario(ALL_SENSORS, ROBOT) if scenario == "all_sensors" else resolve_scenario(scenario, ROBOT))
    compiled = run_headless(ROBOT, scen, "trot_35", 1.2, seed=3, progress=False)
    stepwise = run_headless(ROBOT, scen, "trot_35", 1.2, seed=3, progress=False,
                            epsilon_fn=lambda ref: np.zeros(ROBOT.nv))
    assert compiled.timings["compiled_s"] > 0 and stepwise.timings["compiled_s"] == 0
    # the compiled loop hands back only a few ticks (the noise blocks'); counted, not timed
    assert stepwise.python_ticks > 20 * max(compiled.python_ticks, 1)
    _same_runs(compiled, stepwise)


def test_compiled_closed_loop_hands_qp_failures_back(monkeypatch):
    """A controller whose QP always fails (f_min · 4 feet > m g): every tick goes back to
    Python for the fallback torque, and the run equals the step-by-step one."""
    from ciml_control.controller import IdController

    make = recorder.make_controller
    monkeypatch.setattr(recorder, "make_controller",
                        lambda robot, motion, q: (IdController(robot, f_min=400.0),) + make(robot, motion, q)[1:])
    scen = resolve_scenario("nominal", ROBOT)
    compiled = run_headless(ROBOT, scen, "stand", 0.2, seed=0, progress=False, settle_time=0.02)
    stepwise = run_headless(ROBOT, scen, "stand", 0.2, seed=0, progress=False, settle_time=0.02,
                            epsilon_fn=lambda ref: np.zeros(ROBOT.nv))
    assert compiled.qp_failures == len(compiled.t) == 50
    _same_runs(compiled, stepwise)


@pytest.mark.slow
def test_robot_stands_30_s_on_the_nominal_scenario_without_drifting():
    result = run_headless(ROBOT, resolve_scenario("nominal", ROBOT), "stand", 30.0, seed=0, progress=False)
    m = result.metrics()
    assert not m["fell"] and m["samples"] == 30 * 250
    err = np.array(result.base_position_error)
    assert err.max() < 0.005                       # [m] never more than 5 mm off
    assert abs(err[-250:].mean() - err[250:500].mean()) < 0.001  # no drift between second 1 and 30
    assert m["rms_attitude_error_deg"] < 0.2 and m["rms_joint_error_deg"] < 1.0


BAGS = os.path.join(os.path.dirname(__file__), "..", "..", "bags")


@pytest.mark.parametrize("name, seconds, truth", [("nominal_stand", 8, False), ("nominal_base", 6, True),
                                                   ("default_gap_base", 6, True)])
def test_committed_bags_are_readable_robot_logs(name, seconds, truth):
    """bags/ (tools/make_bags.sh): documented topics at 250 Hz; ground truth where promised."""
    path = os.path.join(BAGS, name)
    found = list_topics(path)
    assert LIVE <= set(found)
    assert any(topics.is_ground_truth(t) for t in found) == truth
    log = load_log(ROBOT, path)
    assert len(log) == seconds * 250 - 1 and np.allclose(np.diff(log.t), 0.004)
    assert log.q[:, 2].min() > 0.5  # standing all along
    if name == "default_gap_base":
        # Γ = τ − u of the sensors is the actuator effects' ground truth plus the 0.5 Nm torque noise
        msgs = read_messages(path, [t for t in found if t.startswith(topics.SIM_EFFECT_PREFIX)])
        act = sum(np.array([m.values for _, m in msgs[t]]) for t in msgs if "actuator_lag" in t or "torque_gain" in t)
        resid = (log.tau - log.u) - act[1:, 6:]
        assert resid.std() == pytest.approx(0.5, rel=0.1) and abs(resid.mean()) < 0.05


def test_cli_extract_of_bags_at_two_rates_says_both(tmp_path):
    """`ciml extract` of a 250 Hz and a 500 Hz bag prints both rates, not one of them."""
    bags = []
    for rate in ("250", "500"):
        bags.append(str(tmp_path / f"bag{rate}"))
        r = subprocess.run([CIML, "record", "--scenario", "nominal", "--motion", "stand", "--duration", "1.0",
                            "--sensor-rate", rate, "--no-ground-truth", "--out", bags[-1]],
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
    r = subprocess.run([CIML, "extract", "--bag", *bags, "--out", str(tmp_path / "t.npz")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.strip().splitlines()[-1])["rate_hz"] == [250.0, 500.0]


def test_cli_sensor_rate_writes_sensors_at_that_rate(tmp_path):
    """`ciml record --sensor-rate 500`: sensor topics at 500 Hz, one /torque_command per 250 Hz tick."""
    out = tmp_path / "bag500"
    r = subprocess.run([CIML, "record", "--scenario", "nominal", "--motion", "stand", "--duration", "0.4",
                        "--sensor-rate", "500", "--no-ground-truth", "--out", str(out)],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    summary = json.loads(r.stdout.strip().splitlines()[-1])
    assert summary["sensor_rate_hz"] == 500.0
    assert (summary["samples"], summary["control_ticks"]) == (200, 100)  # what the bag holds, and the ticks
    stamps = {}
    for topic, stamp, _raw, _ in bagio.iter_bag_messages(out):
        stamps.setdefault(topic, []).append(stamp)
    assert len(stamps["/joint_states"]) == 2 * len(stamps["/torque_command"]) == 200
    assert np.allclose(np.diff(sorted(stamps["/joint_states"])), 2e6)
