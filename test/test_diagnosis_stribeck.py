"""Joint Stribeck friction, added to the catalogue through the effect registry alone (issue 29), on
the simulator's logs: named with its parameters inside their intervals, and a Coulomb-only log does not
turn into Stribeck friction (the Stribeck candidate nests the Coulomb one; its extra parameters must pay
for themselves on held-out data, and a Stribeck fit that is not consistent across contact
configurations and speeds falls back to Coulomb). Both need the stick phases left out of the fit: there
MuJoCo's friction is whatever holds the joint (diagnosis/shrink.py, "Stiction")."""
from __future__ import annotations

import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(__file__))
from diag_data import record_plant_bag  # noqa: E402

from ciml_learning.core.robot import load_robot  # noqa: E402
from ciml_learning.diagnosis.run import diagnose  # noqa: E402

ROBOT = load_robot()
STRIBECK = {"type": "joint_stribeck_friction", "joint": "lf_kfe_joint", "breakaway": 12.0, "coulomb": 4.0,
            "velocity": 0.15}  # between two of the layout's velocity columns (0.1, 0.2)
COULOMB = {"type": "joint_coulomb_friction", "joint": "lf_kfe_joint", "value": 8.0}


def _diagnose(tmp_path, effect: dict, seed: int) -> dict:
    bag = str(tmp_path / effect["type"])
    scenario = {"name": "probe", "seed": seed, "sensor_noise": {"tau": 0.2}, "effects": [effect]}
    info = record_plant_bag(ROBOT, scenario, bag, seconds=12.0, seed=seed)
    assert not info["fell"]
    return diagnose(ROBOT, [bag], None, None, progress=False)


def test_stribeck_friction_is_named_with_its_parameters(tmp_path):
    d = _diagnose(tmp_path, STRIBECK, 6)
    strib = [e for e in d["effects"] if e["type"] == "joint_stribeck_friction"]
    assert len(strib) == 1 and strib[0]["joint"] == STRIBECK["joint"], d["effects"]
    assert not [e for e in d["effects"] if e["type"] == "joint_coulomb_friction" and e["share"] > 0.05]
    p, lo_hi = strib[0]["params"], strib[0]["interval_95"]
    for key, rel in (("breakaway", 0.1), ("coulomb", 0.1), ("velocity", 0.1)):  # measured 11.67, 4.01, 0.148
        assert p[key] == pytest.approx(STRIBECK[key], rel=rel), (key, p)
        assert lo_hi[key][0] <= STRIBECK[key] <= lo_hi[key][1], (key, strib[0])
    assert strib[0]["share"] > 0.5


def test_coulomb_friction_does_not_turn_into_stribeck(tmp_path):
    d = _diagnose(tmp_path, COULOMB, 7)
    assert not [e for e in d["effects"] if e["type"] == "joint_stribeck_friction"], d["effects"]
    coul = [e for e in d["effects"] if e["type"] == "joint_coulomb_friction" and e["joint"] == COULOMB["joint"]]
    assert coul and coul[0]["params"]["value"] == pytest.approx(COULOMB["value"], rel=0.05)  # measured 7.97


@pytest.mark.slow
def test_stribeck_friction_above_the_stick_speed_is_named_on_walking_logs(tmp_path):
    """Stribeck velocity 0.3 rad/s on gap-bench's kind of logs (case 19: walk and trot to identify, a
    slower trot held out): named as Stribeck friction at the right joint, every parameter inside its
    95 % interval. Measured: breakaway 11.76 ± 1.12 Nm (12), Coulomb 4.16 ± 0.48 Nm (4), velocity
    0.298 ± 0.034 rad/s (0.3), share 0.85. Before stuck joints were projected out (shrink.py, "Stiction"):
    16.5 ± 5.1, 4.57 ± 0.86, 0.137 ± 0.041 (the stick phases pulled the velocity down)."""
    from ciml_learning.cli.main import main

    truth = {"type": "joint_stribeck_friction", "joint": "rf_kfe_joint", "breakaway": 12.0, "coulomb": 4.0,
             "velocity": 0.3}
    scenario = tmp_path / "s.yaml"
    scenario.write_text(f"name: s\nseed: 19\neffects:\n  - {truth}\n".replace("'", ""))
    bags = []
    for motion, seconds in (("walk_35", 16), ("trot_35", 8), ("trot_20", 8)):
        bags.append(str(tmp_path / motion))
        assert main(["record", "--scenario", str(scenario), "--motion", motion, "--duration", str(seconds),
                     "--seed", "1", "--no-ground-truth", "--out", bags[-1]]) == 0
    d = diagnose(ROBOT, bags[:2], bags[2:], None, progress=False)
    strib = [e for e in d["effects"] if e["type"] == "joint_stribeck_friction"]
    assert len(strib) == 1 and strib[0]["joint"] == truth["joint"], d["effects"]
    for key in ("breakaway", "coulomb", "velocity"):
        lo, hi = strib[0]["interval_95"][key]
        assert lo <= truth[key] <= hi, (key, strib[0])
    assert strib[0]["share"] > 0.5 and d["data"]["stuck_joints_projected_out"] == [truth["joint"]]
