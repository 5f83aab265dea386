"""Does the diagnosis depend on the log's sample rate? (issue 19: a 448 Hz log must give the
same identified actuator lag as its 250 Hz resampling.)

Records one simulated bag with 1 kHz sensor topics (the controller and its /torque_command
stay at 250 Hz), resamples the sensor topics explicitly onto 448 Hz and 250 Hz grids (linear
interpolation; quaternions normalised; contacts held), diagnoses all three and prints the
identified effects' parameters side by side.

    python tools/rate_study.py --scenario default_gap --motion trot_35 --duration 20 --out out/rate_study
"""
from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np


def resample_bag(robot, src: str, dst: str, rate_hz: float) -> None:
    from ciml_learning import conversions as cv
    from ciml_learning import topics
    from ciml_learning.bagio import BagWriter, iter_bag_messages, read_messages
    from ciml_learning.stamps import resample

    data = read_messages(src, topics.MEASUREMENT_TOPICS)
    tj = np.array([s for s, _ in data[topics.JOINT_STATES]]) * 1e-9
    js = [cv.joint_state_arrays(robot, m) for _, m in data[topics.JOINT_STATES]]
    tb = np.array([s for s, _ in data[topics.BASE_STATE]]) * 1e-9
    base = [cv.odometry_arrays(m) for _, m in data[topics.BASE_STATE]]
    tc = np.array([s for s, _ in data[topics.CONTACT_STATE]]) * 1e-9
    con = np.array([cv.contact_state_arrays(robot, m) for _, m in data[topics.CONTACT_STATE]])
    grid, J = resample(tj, np.array([np.concatenate(x) for x in js]), rate_hz)
    _, B = resample(tb, np.array([np.concatenate(x) for x in base]), rate_hz)
    nj = robot.n_joints
    with BagWriter(dst) as w:
        for k, t in enumerate(grid):
            ns = int(round(t * 1e9))
            w.write(topics.JOINT_STATES, ns, cv.joint_state_msg(robot, ns, J[k, :nj], J[k, nj:2 * nj], J[k, 2 * nj:]))
            quat = B[k, 3:7] / np.linalg.norm(B[k, 3:7])
            w.write(topics.BASE_STATE, ns, cv.odometry_msg(ns, B[k, :3], quat, B[k, 7:10], B[k, 10:13]))
            i = max(0, int(np.searchsorted(tc, t, side="right")) - 1)
            w.write(topics.CONTACT_STATE, ns, cv.contact_state_msg(robot, ns, con[i]))
        for topic, log_ns, raw, typ in iter_bag_messages(src):
            if topic == topics.TORQUE_COMMAND:
                w.write_serialized(topic, log_ns, raw, typ)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="default_gap")
    ap.add_argument("--motion", default="trot_35")
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="out/rate_study")
    a = ap.parse_args()
    from ciml_learning.bagio import BagWriter
    from ciml_learning.diagnosis.run import diagnose
    from ciml_learning.robot import load_robot
    from ciml_sim.recorder import run_headless
    from ciml_sim.scenario import resolve_scenario

    robot = load_robot()
    os.makedirs(a.out, exist_ok=True)
    src = os.path.join(a.out, "bag_1000hz")
    if not os.path.exists(src):
        with BagWriter(src, compression="zstd") as w:
            run_headless(robot, resolve_scenario(a.scenario, robot), a.motion, a.duration, a.seed, writer=w,
                         ground_truth=False, progress=True, sensor_rate=1000.0)
    bags = {1000.0: src}
    for rate in (448.0, 250.0):
        dst = os.path.join(a.out, f"bag_{rate:.0f}hz")
        if not os.path.exists(dst):
            resample_bag(robot, src, dst, rate)
        bags[rate] = dst
    results = {}
    for rate, bag in bags.items():
        res = diagnose(robot, [bag], out_dir=None, progress=False, report=False)
        results[rate] = {"rate_hz": res["data"]["rate_hz"],
                         "effects": {f"{e['type']}:{e.get('joint', e.get('link', ''))}": e["params"]
                                     for e in res["effects"]}}
        print(json.dumps({rate: results[rate]}), flush=True)
    with open(os.path.join(a.out, "rate_study.json"), "w") as f:
        json.dump({str(k): v for k, v in results.items()}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
