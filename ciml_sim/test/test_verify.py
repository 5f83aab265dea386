"""`ciml verify`: the sim-to-real gap before (nominal) and after (identified scenario) re-simulation,
next to the oracle (docs/DIAGNOSIS.md, "The re-simulated shrink"); bad input writes nothing."""
from __future__ import annotations

import json
import os

import pytest
import yaml

from ciml_learning.cli import main as cli
from ciml_learning.core.robot import load_robot
from ciml_learning.logs import bagio
from ciml_sim.recorder import record_bag
from ciml_sim.scenario import parse_scenario
from ciml_sim.verify import bag_motion

ROBOT = load_robot()
TRUTH = {"name": "truth", "seed": 3, "effects": [{"type": "joint_viscous_friction", "joint": "lh_hfe_joint",
                                                  "value": 4.0}]}


def _diagnosis(path, value: float) -> str:
    """A diagnosis folder whose identified scenario holds the truth's friction at `value`."""
    os.makedirs(path)
    ident = {"name": "identified", "seed": 0, "sensor_noise": {},
             "effects": [{"type": "joint_viscous_friction", "joint": "lh_hfe_joint", "value": value}]}
    (path / "identified_scenario.yaml").write_text(yaml.safe_dump(ident))
    (path / "diagnosis.json").write_text(json.dumps({"shrink": {"ratio": 0.9, "ratio_physical_per_dimension": 0.95}}))
    return str(path)


@pytest.fixture(scope="module")
def real_bag(tmp_path_factory) -> str:
    """The "real" log: 2 s of trot with a knee-high viscous friction, as `ciml record` writes it."""
    out = str(tmp_path_factory.mktemp("real") / "real")
    record_bag(ROBOT, parse_scenario(TRUTH, ROBOT), "trot_35", 2.0, 7, out, ground_truth=False, progress=False)
    return out


def test_verify_before_after_and_oracle_on_a_known_friction(real_bag, tmp_path, capsys):
    """A friction identified 5 % low removes ~95 % of the gap; the oracle (the true scenario) reproduces
    the log exactly (the plant is deterministic and every run is noise-free); nominal is far."""
    assert bag_motion(real_bag) == ("trot_35", 0)
    oracle = tmp_path / "truth.yaml"
    oracle.write_text(yaml.safe_dump(TRUTH))
    out = tmp_path / "verify"
    rc = cli.main(["verify", "--real", real_bag, "--diagnosis", _diagnosis(tmp_path / "diag", 3.8),
                   "--oracle", str(oracle), "--out", str(out)])
    printed = capsys.readouterr().out
    assert rc == 0 and "shrink" in printed
    doc = json.loads((out / "verify.json").read_text())
    o = doc["resimulated_shrink"]["overall"]
    assert o["gap_nominal"] > 1.0                      # N, Nm: the friction's force is far above rounding
    assert o["gap_oracle"] < 1e-6 * o["gap_nominal"] and o["shrink_oracle"] > 0.999999
    assert 0.90 < o["shrink"] < 0.99 and not o["further_than_nominal"]
    assert 0.90 < o["shrink_of_oracle"] < 0.99
    per = doc["resimulated_shrink"]["per_dimension"]
    top = max(per, key=lambda n: per[n]["gap_nominal"])
    assert top.startswith("foot_lh") and per[top]["unit"] == "N"   # the friction's leg, while it swings
    assert 0.02 < per[top]["gap_identified"] / per[top]["gap_nominal"] < 0.10
    assert not doc["resimulated_shrink"]["worsened_dimensions"]
    assert doc["torque"]["overall"]["shrink"] > 0.9
    assert doc["regression_shrink"]["ratio"] == 0.9          # the regression shrink stays beside it
    assert doc["bags"][0]["motion"] == "trot_35" and doc["bags"][0]["duration_s"] == 2.0


def test_a_diagnosis_without_identified_scenario_is_refused(real_bag, tmp_path, capsys):
    diag = tmp_path / "old_diag"
    diag.mkdir()
    (diag / "diagnosis.json").write_text("{}")
    out = tmp_path / "verify"
    assert cli.main(["verify", "--real", real_bag, "--diagnosis", str(diag), "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "identified_scenario.yaml" in err
    assert not out.exists() and not any(p.name.startswith(".verify") for p in tmp_path.iterdir())


def test_a_log_without_a_motion_needs_motion(real_bag, tmp_path, capsys):
    """A log naming no motion (no /reference, no recorded motion): one line; --motion names it."""
    from ciml_learning.core.errors import CimlError
    from ciml_sim.verify import check_logs

    bare = tmp_path / "bare"
    with bagio.BagWriter(bare) as w:  # the same messages, without the recorded motion
        for topic, ns, raw, msgtype in bagio.iter_bag_messages(real_bag):
            w.write_serialized(topic, ns, raw, msgtype)
    assert bag_motion(str(bare)) is None
    out = tmp_path / "verify"
    rc = cli.main(["verify", "--real", str(bare), "--diagnosis", _diagnosis(tmp_path / "diag", 4.0),
                   "--out", str(out)])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and len(err.splitlines()) == 1 and "--motion" in err and not out.exists()
    assert check_logs([str(bare)], "trot_35") == [(str(bare), "trot_35", 0)]
    with pytest.raises(CimlError, match="unknown motion"):
        check_logs([str(bare)], "moonwalk")


def test_a_live_graph_log_names_its_motion_on_reference(real_bag, tmp_path):
    """A log of the live graph: the motion of its first /reference message, which starts the clock."""
    from ciml_control.conversions import reference_msg
    from ciml_control.references import make_reference, standing_configuration

    point = make_reference(ROBOT, "walk_20", standing_configuration(ROBOT)).sample(0.0)
    live = tmp_path / "live"
    with bagio.BagWriter(live) as w:
        for topic, ns, raw, msgtype in bagio.iter_bag_messages(real_bag):
            w.write_serialized(topic, ns + 5_000_000_000, raw, msgtype)
        w.write("/reference", 5_000_000_000, reference_msg(ROBOT, 5_000_000_000, point))
    assert bag_motion(str(live)) == ("walk_20", 5_000_000_000)
