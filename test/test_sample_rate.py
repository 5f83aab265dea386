"""The identified actuator lag does not depend on the log's sample rate (issue 19).

A 250 Hz assumption scaled a 448 Hz log's accelerations and torque rates by 250/448 and
its identified lag with them (16.05 ms instead of 9.2 ms). Here one HyQ recording of the
default gap (actuator lag 10 ms on every joint, knee friction, a payload, a weak hip,
sensor noise) is made with 1 kHz sensor topics (the controller and its /torque_command
at 250 Hz, as a robot whose estimator publishes faster than its controller), resampled
onto a 448 Hz grid and that log onto 250 Hz grids with the library's own
`stamps.resample` (linear interpolation; quaternions normalised; contacts held), and
diagnosed from the bags alone: the rate is measured from the stamps and the filters are
designed for it.

Two 250 Hz resamplings of the 448 Hz log:
- `250`: its grid starts half a command period (2 ms) after the first stamp, so no sample
  falls on a command instant — a resampling of a robot's log has no relation to its
  controller's clock. The lag must agree with the 448 Hz one within 10 %, and each 95 %
  interval must hold the true 10 ms.
- `250_on_ticks`: the grid starts at the first stamp, which is a command instant: every
  sample falls on one, as in a log written at the controller's tick. There the log holds,
  at each sample, the torque at the very end of a command step, and the lag's coefficient
  reads low (docs/DIAGNOSIS.md, "What an actuator lag reads in a log"); the diagnosis
  converts it with the samples' phases in the command period and the command's staircase
  share, which the log reader measures. Both 250 Hz lags must agree with the 448 Hz one
  within 10 % and each 95 % interval must hold the true 10 ms.

Measured on the 2-core machine (`pytest -s test/test_sample_rate.py`, load ~8): 448 Hz
9.60 ± 0.66 ms, 250 Hz 9.62 ± 1.17 ms (448/250 = 0.998), 250 Hz on the ticks 9.26 ± 1.48 ms
(448/250 = 1.036); 3 min 40 s wall. Before the conversion read the samples' phase (commit
800682b): 10.13 ± 0.57, 10.49 ± 0.96 and 8.34 ± 1.25 ms (448/250 on the ticks = 1.21).
The log reader measures, for this recording, the staircase share of the command's rate
0.99 (all joints pooled) and the command period 4 ms; the sample phases are uniform at
448 Hz, 0.5 of the period off the ticks and 1.0 (on the command instants) on them.
"""
from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("ciml_sim")

SCENARIO = "default_gap"
MOTION = "trot_35"
DURATION = 20.0      # [s] one bag; the diagnosis holds out its last 30 %
TRUE_LAG = 0.010     # [s] default_gap.yaml: actuator_lag on every joint
COMMAND_PERIOD = 0.004  # [s] the recorder's controller runs at 250 Hz
AGREEMENT = 0.10     # relative, between the two rates


def resample_bag(robot, src: str, dst: str, rate_hz: float, offset: float = 0.0) -> None:
    """`src` (CIML's own topics) with its sensor topics resampled onto a uniform `rate_hz` grid
    starting `offset` [s] after its first stamp (stamps.resample: linear interpolation; the
    quaternion renormalised; contacts: the latest at or before each instant); /torque_command
    copied as recorded (its own stamps, 250 Hz)."""
    from ciml_learning.core import conversions as cv
    from ciml_learning.core import topics
    from ciml_learning.core.stamps import resample
    from ciml_learning.logs.bagio import BagWriter, iter_bag_messages, read_messages

    data = read_messages(src, topics.MEASUREMENT_TOPICS)
    tj = np.array([s for s, _ in data[topics.JOINT_STATES]]) * 1e-9
    js = np.array([np.concatenate(cv.joint_state_arrays(robot, m)) for _, m in data[topics.JOINT_STATES]])
    tb = np.array([s for s, _ in data[topics.BASE_STATE]]) * 1e-9
    base = np.array([np.concatenate(cv.odometry_arrays(m)) for _, m in data[topics.BASE_STATE]])
    tc = np.array([s for s, _ in data[topics.CONTACT_STATE]]) * 1e-9
    con = np.array([cv.contact_state_arrays(robot, m) for _, m in data[topics.CONTACT_STATE]])
    start = tj[0] + offset
    grid, J = resample(tj, js, rate_hz, start)
    _, B = resample(tb, base, rate_hz, start)
    nj = robot.n_joints
    with BagWriter(dst) as w:
        for k, t in enumerate(grid):
            ns = int(round(t * 1e9))
            w.write(topics.JOINT_STATES, ns, cv.joint_state_msg(robot, ns, J[k, :nj], J[k, nj:2 * nj], J[k, 2 * nj:]))
            quat = B[k, 3:7] / np.linalg.norm(B[k, 3:7])
            w.write(topics.BASE_STATE, ns, cv.odometry_msg(ns, B[k, :3], quat, B[k, 7:10], B[k, 10:13]))
            i = max(0, int(np.searchsorted(tc, t + 1e-9, side="right")) - 1)
            w.write(topics.CONTACT_STATE, ns, cv.contact_state_msg(robot, ns, con[i]))
        for topic, log_ns, raw, typ in iter_bag_messages(src):
            if topic == topics.TORQUE_COMMAND:
                w.write_serialized(topic, log_ns, raw, typ)


@pytest.fixture(scope="module")
def lags(tmp_path_factory):
    """{name: (lag [s], its 95 % interval)} of the 448 Hz resampling of a 1 kHz recording and
    of that log's two 250 Hz resamplings (module docstring)."""
    from ciml_learning.core.robot import load_robot
    from ciml_learning.diagnosis.run import diagnose
    from ciml_learning.logs.bagio import BagWriter
    from ciml_sim.recorder import run_headless
    from ciml_sim.scenario import resolve_scenario

    robot = load_robot()
    root = tmp_path_factory.mktemp("rates")
    src = str(root / "bag_1000hz")
    with BagWriter(src, compression="zstd") as w:
        r = run_headless(robot, resolve_scenario(SCENARIO, robot), MOTION, DURATION, 1, writer=w,
                         ground_truth=False, progress=False, sensor_rate=1000.0)
    assert not r.fell
    bags = {"448": (str(root / "bag_448"), 448.0, src, 0.0),
            "250": (str(root / "bag_250"), 250.0, str(root / "bag_448"), COMMAND_PERIOD / 2),
            "250_on_ticks": (str(root / "bag_250_on_ticks"), 250.0, str(root / "bag_448"), 0.0)}
    out = {}
    for name, (bag, rate, parent, offset) in bags.items():
        resample_bag(robot, parent, bag, rate, offset)
        res = diagnose(robot, [bag], None, None, progress=False, report=False)
        assert res["data"]["rate_hz"] == pytest.approx(rate, rel=1e-6), "rate not measured from the stamps"
        found = [e for e in res["effects"] if e["type"] == "actuator_lag"]
        assert found, f"{name} Hz: no actuator lag named: {[e['type'] for e in res['effects']]}"
        e = found[0]
        out[name] = (e["params"]["time_constant"], e["interval_95"]["time_constant"])
        print(f"\n{name} Hz: lag {out[name][0] * 1e3:.2f} ms ± {e['std']['time_constant'] * 1e3:.2f} "
              f"(95 %: {out[name][1][0] * 1e3:.2f}–{out[name][1][1] * 1e3:.2f}), {res['data']['samples']} samples, "
              f"{res['time_s']:.0f} s")
    return out


def _check(lags, a: str, b: str) -> None:
    for name in (a, b):
        lag, (lo, hi) = lags[name]
        assert lo <= TRUE_LAG <= hi, f"{name} Hz: true lag {TRUE_LAG * 1e3} ms outside {lo * 1e3:.2f}–{hi * 1e3:.2f} ms"
    la, lb = lags[a][0], lags[b][0]
    print(f"{a} / {b} Hz: {la / lb:.4f}")
    assert abs(la - lb) <= AGREEMENT * lb, f"{a} Hz: {la * 1e3:.2f} ms, {b} Hz: {lb * 1e3:.2f} ms"


@pytest.mark.slow
def test_448_hz_log_gives_the_lag_of_its_250_hz_resampling(lags):
    _check(lags, "448", "250")


@pytest.mark.slow
def test_250_hz_resampling_on_the_command_ticks(lags):
    _check(lags, "448", "250_on_ticks")
