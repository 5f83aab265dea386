"""End to end: a robot other than HyQ (go1), logged in other robots' layouts, diagnosed.

A go1 with injected effects (ciml_sim/config/scenarios/go1_gap.yaml: actuator lag, calf
friction, a payload, sensor noise) is recorded natively at 1 kHz sensor rate (the
controller at 250 Hz) and rewritten by test/foreign_layouts.py as
(a) a Unitree-like log at 500 Hz (JointState with foot-sensor entries, an IMU, foot forces
    as an array, the efforts as a Float64MultiArray; no odometry, no contact flags),
(b) a ros2_control-like log at 1 kHz (/joint_states, /imu, /odom with a world-frame twist,
    an effort command; no contact topic),
(c) the Unitree log again as a rosbag2 sqlite3 (db3) bag and as a ROS 1 .bag.
Each is read through its robot profile (docs/ROBOT_PROFILE.md) and diagnosed; the
diagnosis must name the effects it names on the native log, with parameters within 10 %.
The tests never give the diagnosis the scenario: only the bags and a profile.

Held-out data: a second, shorter recording of every motion (another seed), given as held-out
bags (`ciml diagnose --heldout`). Without them the diagnosis holds out whole bags — here the
last one, base_only — and then selects and shares the effects on a stance-only motion in
which the feet never swing and the torques change slowly: measured, the actuator lag was
2 % of the gap there (33 % on the trot) and the test's MIN_SHARE dropped it.
"""
from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from ciml_learning.core.robot import example_robot_data_dir, load_robot
from ciml_learning.logs import bagio

pytest.importorskip("ciml_sim")
sys.path.insert(0, os.path.dirname(__file__))
import foreign_layouts as fl  # noqa: E402

from ciml_learning.core.profile import load_profile, profile_from_dict  # noqa: E402,F401
from ciml_learning.logs.loginputs import load_log  # noqa: E402

GO1_FEET = ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
SCENARIO = os.path.join(os.path.dirname(__file__), "..", "ciml_sim", "config", "scenarios", "go1_gap.yaml")
DURATION = 8.0          # [s] per motion
HELDOUT_DURATION = 4.0  # [s] per motion, held out (seed HELDOUT_SEED)
HELDOUT_SEED = 2
MOTIONS = ("trot_20", "base_only")
PARAM_TOLERANCE = 0.10  # relative, against the native layout's result
MIN_SHARE = 0.05
"""Effects compared between layouts: those the native diagnosis gives at least this share of
the gap (smaller ones are at the noise level of the selection and may come and go)."""


def _go1():
    return load_robot(os.path.join(example_robot_data_dir(), "go1_description", "urdf", "go1.urdf"), GO1_FEET)


def test_recorder_sensor_rate_option(tmp_path):
    """sensor_rate 1000 Hz: four sensor samples per control tick, one command per tick, 1 ms
    apart; an unsupported rate is refused."""
    from ciml_sim.recorder import RecordError, run_headless
    from ciml_sim.scenario import resolve_scenario

    robot = _go1()
    scen = resolve_scenario(SCENARIO, robot)
    with bagio.BagWriter(tmp_path / "b") as w:
        run_headless(robot, scen, "stand", 0.2, 0, writer=w, ground_truth=True, progress=False, sensor_rate=1000.0)
    assert w.counts["/joint_states"] == 4 * w.counts["/torque_command"] == 200
    assert w.counts["/sim/contact_forces"] == 200
    js = bagio.read_messages(tmp_path / "b", ["/joint_states"])["/joint_states"]
    assert np.allclose(np.diff([s for s, _ in js]), 1_000_000)
    with pytest.raises(RecordError, match="sensor rate"):
        run_headless(robot, scen, "stand", 0.2, 0, progress=False, sensor_rate=300.0)


# --- the recordings (module scope: recorded once) ----------------------------------------------


@pytest.fixture(scope="module")
def go1_native(tmp_path_factory):
    from ciml_sim.recorder import run_headless
    from ciml_sim.scenario import resolve_scenario

    robot = _go1()
    scen = resolve_scenario(SCENARIO, robot)
    root = tmp_path_factory.mktemp("go1")
    out = {"robot": robot, "root": root}
    for part, duration, seed in (("", DURATION, 1), ("heldout_", HELDOUT_DURATION, HELDOUT_SEED)):
        bags, logs = [], []
        for motion in MOTIONS:
            path = root / f"native_{part}{motion}"
            with bagio.BagWriter(path, compression="zstd") as w:
                r = run_headless(robot, scen, motion, duration, seed=seed, writer=w, ground_truth=True,
                                 progress=False, sensor_rate=1000.0)
            assert not r.fell
            bags.append(str(path))
            logs.append(fl.read_native(robot, path))
        out[part + "bags"], out[part + "logs"] = bags, logs
    return out


def _write(go1_native, layout: str, storage: str = "mcap", command: bool = True,
           part: str = "") -> tuple[list[str], dict]:
    """The native recordings (`part` "": identification, "heldout_": held out) rewritten in
    `layout` (unitree: 500 Hz, ros2_control: 1 kHz); (bags, profile dict); written once per
    (layout, storage, command, part)."""
    cache = go1_native.setdefault("written", {})
    key = (layout, storage, command, part)
    if key not in cache:
        robot, root = go1_native["robot"], go1_native["root"]
        bags, prof = [], None
        for motion, log in zip(MOTIONS, go1_native[part + "logs"]):
            if layout == "unitree":
                src, writer = fl.decimate(log, 2), fl.write_unitree
            else:
                src, writer = log, fl.write_ros2_control
            path = root / f"{layout}_{storage}_{int(command)}_{part}{motion}"
            if storage == "ros1":
                path = path.with_suffix(".bag")
            prof = writer(robot, src, path, storage=storage, command=command)
            bags.append(str(path))
        cache[key] = (bags, prof)
    return cache[key]


def _diagnose_layout(go1_native, layout: str, storage: str = "mcap", command: bool = True) -> dict:
    """The diagnosis of one layout: identification and held-out bags both in that layout."""
    bags, prof = _write(go1_native, layout, storage, command)
    heldout, _ = _write(go1_native, layout, storage, command, part="heldout_")
    if not command:
        prof = fl.without_command(prof)
    return _diagnose(go1_native["robot"], bags, heldout, prof)


def _diagnose(robot, bags, heldout, profile: dict) -> dict:
    from ciml_learning.diagnosis.run import diagnose

    return diagnose(robot, bags, heldout, None, progress=False, report=False, profile=profile_from_dict(profile))


def _key(effect: dict) -> tuple:
    return effect["type"], effect.get("joint") or effect.get("link") or ""


def _flat_params(effect: dict) -> dict[str, float]:
    out = {}
    for name, value in effect["params"].items():
        for i, x in enumerate(np.atleast_1d(value)):
            out[f"{name}[{i}]" if np.ndim(value) else name] = float(x)
    return out


def _compare(native: dict, other: dict, what: str, skip_types: tuple[str, ...] = (),
             names_only: tuple[str, ...] = (), only: tuple[str, ...] = ()) -> None:
    """The effects the native diagnosis gives ≥ MIN_SHARE of the gap are named on `other`,
    with every scalar parameter within PARAM_TOLERANCE (a CoM coordinate: within 10 % of the
    CoM vector's length — a component near zero has no relative scale — or within the two
    estimates' combined standard deviation when that is larger: go1's payload CoM height is
    known to ±0.02 m on either log, twice 10 % of its 0.09 m CoM); `names_only` types are
    only required to be named, `only` restricts the comparison to those types."""
    theirs = {_key(e): e for e in other["effects"]}
    for e in native["effects"]:
        if e["share"] < MIN_SHARE or e["type"] in skip_types or (only and e["type"] not in only):
            continue
        k = _key(e)
        assert k in theirs, f"{what}: {k} named on the native log (share {e['share']:.2f}) but not here: " \
                            f"{sorted(theirs)}"
        if e["type"] in names_only:
            continue
        mine, their = _flat_params(e), _flat_params(theirs[k])
        std_mine, std_their = _flat_params({"params": e["std"]}), _flat_params({"params": theirs[k]["std"]})
        com_scale = np.linalg.norm(e["params"]["com"]) if "com" in e["params"] else 0.0
        for p, x in mine.items():
            tolerance = PARAM_TOLERANCE * (com_scale if p.startswith("com") else abs(x))
            if p.startswith("com"):
                tolerance = max(tolerance, float(np.hypot(std_mine[p], std_their[p])))
            assert abs(their[p] - x) <= tolerance, f"{what}: {k} {p} = {their[p]:.4g}, native {x:.4g}"


@pytest.fixture(scope="module")
def native_diagnosis(go1_native):
    result = _diagnose(go1_native["robot"], go1_native["bags"], go1_native["heldout_bags"],
                       fl.native_profile(go1_native["robot"]))
    named = {_key(e) for e in result["effects"] if e["share"] >= MIN_SHARE}
    # the native log's own diagnosis finds the injected kinds (the reference of the comparisons)
    assert {"payload", "actuator_lag"} <= {t for t, _ in named}, named
    return result


# --- the layouts read like the native log ------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("storage", fl.STORAGES)
def test_unitree_layout_reads_like_the_native_log(go1_native, storage):
    """Unitree-like log (MCAP, db3, ROS 1): read through its profile, the joint torques and
    the command are the native log's at the same stamps, the contacts from the foot forces
    agree ≥ 98 %, the base velocity estimated from IMU + legs is within 0.03 m/s RMS of the
    recorded odometry's, and the measured rate is 500 Hz; all three containers give the same
    arrays."""

    robot = go1_native["robot"]
    bags, prof = _write(go1_native, "unitree", storage)
    ref_bags, _ = _write(go1_native, "unitree", "mcap")
    for bag, ref_bag, nat in zip(bags, ref_bags, go1_native["logs"]):
        log = load_log(robot, bag, profile_from_dict(prof))
        assert log.rate_hz == pytest.approx(500.0, rel=1e-6)
        assert log.u_observed and not any("unknown" in w for w in log.warnings)
        idx = np.searchsorted(nat.t, log.t - 1e-7)
        np.testing.assert_allclose(log.tau, nat.tau[idx], atol=1e-9)
        np.testing.assert_allclose(log.u, nat.u[idx], atol=1e-9)
        assert (log.contacts == nat.contacts[idx]).mean() >= 0.98
        assert np.all(np.sqrt(np.mean((log.v[:, :3] - nat.v[idx, :3]) ** 2, axis=0)) < 0.03)
        if storage != "mcap":
            ref = load_log(robot, ref_bag, profile_from_dict(prof))
            for f in ("t", "q", "v", "tau", "u", "contacts"):
                np.testing.assert_array_equal(getattr(log, f), getattr(ref, f), err_msg=f)


# --- the diagnosis on each layout ----------------------------------------------------------------


@pytest.fixture(scope="module")
def unitree_diagnosis(go1_native):
    return _diagnose_layout(go1_native, "unitree")


@pytest.mark.slow
def test_unitree_layout_diagnosis_matches_native(native_diagnosis, unitree_diagnosis):
    """Every effect named as on the native log, parameters within 10 %; the actuator lag's
    value is compared by the next test."""
    _compare(native_diagnosis, unitree_diagnosis, "unitree 500 Hz", names_only=("actuator_lag",))


@pytest.mark.slow
def test_unitree_layout_lag_matches_native(native_diagnosis, unitree_diagnosis):
    """The actuator lag within 10 % of the native log's, although a quarter of the native 1 kHz
    log's samples sit on the 250 Hz command instants and none of the 500 Hz Unitree log's (the
    lag's coefficient depends on the samples' phase in the command period; the diagnosis
    converts it with the phases the log reader measures). Measured: native 8.89 ± 0.64 ms
    (coefficient 8.44), Unitree 9.28 ± 0.65 ms (coefficient 9.26); true 10 ms. Before, with the
    sample period taken for the command period (eea41b4): 8.69 vs 9.74 ms."""
    _compare(native_diagnosis, unitree_diagnosis, "unitree 500 Hz", only=("actuator_lag",))


@pytest.mark.slow
def test_ros2_control_layout_diagnosis_matches_native(go1_native, native_diagnosis):
    _compare(native_diagnosis, _diagnose_layout(go1_native, "ros2_control", "sqlite3"), "ros2_control 1 kHz db3")


@pytest.mark.slow
def test_without_command_only_the_rigid_body_effects(go1_native, native_diagnosis):
    """No command topic: the diagnosis names the rigid-body effects (payload, friction) as on
    the native log, names no actuator effect, and says the actuation error is unobservable."""
    result = _diagnose_layout(go1_native, "ros2_control", "mcap", command=False)
    actuator = ("actuator_lag", "torque_gain", "torque_offset")
    assert not [e for e in result["effects"] if e["type"] in actuator], result["effects"]
    _compare(native_diagnosis, result, "no command", skip_types=actuator)
    data = result["data"]
    assert data.get("actuation_observed") is False, data
    assert any("not observable" in w for w in data.get("warnings", [])), data.get("warnings")
