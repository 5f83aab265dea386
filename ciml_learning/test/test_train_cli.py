"""`ciml train` and `ciml evaluate` end to end on a synthetic bag."""
from __future__ import annotations

import json
import os

import numpy as np
import pytest
from synthetic import write_synthetic_bag

from ciml_learning.cli.main import main
from ciml_learning.core.dynamics import ReferenceState
from ciml_learning.core.robot import load_robot
from ciml_learning.learning.model_epsilon import load_epsilon_function
from ciml_learning.learning.models import ModelSet, rbd_output_names

ROBOT = load_robot()


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    path = str(tmp_path_factory.mktemp("bags") / "synthetic")
    write_synthetic_bag(ROBOT, path, seconds=4.0, seed=3)
    return path


def run_train_and_evaluate(bag: str, out_dir, learner: str, jobs: int) -> dict:
    model_dir = str(out_dir / f"model_{learner}")
    assert main(["train", "--bag", bag, "--learner", learner, "--out", model_dir, "--jobs", str(jobs)]) == 0
    ms = ModelSet.load(model_dir, ROBOT)
    assert ms.learner == learner and ms.is_fitted()
    assert ms.training_["bags"] == [bag] and ms.training_["valid_samples"] > 0
    metrics_path = str(out_dir / f"metrics_{learner}.json")
    assert main(["evaluate", "--model", model_dir, "--bag", bag, "--out", metrics_path]) == 0
    with open(metrics_path) as f:
        metrics = json.load(f)
    assert [d["name"] for d in metrics["dimensions"]] == list(rbd_output_names(ROBOT) + ROBOT.joint_names)
    for group in ("rbd", "actuation", "all"):
        assert metrics["summary"][group]["dimensions"] > 0
    # on its own training data the learned model must beat the nominal (zero) model
    assert metrics["summary"]["rbd"]["rmse_learned"] < 0.5 * metrics["summary"]["rbd"]["rmse_nominal"]
    assert metrics["summary"]["all"]["improved_dimensions"] >= 0.8 * metrics["summary"]["all"]["dimensions"]
    eps = load_epsilon_function(ROBOT, model_dir)
    q = ROBOT.neutral_configuration()
    q[7:] = ROBOT.standing_joints
    ref = ReferenceState(0.0, q, np.zeros(ROBOT.nv), np.zeros(ROBOT.nv), np.ones(ROBOT.n_feet, bool))
    assert np.all(np.isfinite(eps(ref)))
    return metrics


def test_train_and_evaluate_lwpr(bag, tmp_path):
    run_train_and_evaluate(bag, tmp_path, "lwpr", jobs=2)  # jobs=2 exercises the joblib (loky) path


@pytest.mark.slow
def test_train_and_evaluate_sgpr(bag, tmp_path):
    run_train_and_evaluate(bag, tmp_path, "sgpr", jobs=2)


def test_cli_errors_are_one_line(bag, tmp_path, capsys):
    assert main(["evaluate", "--model", str(tmp_path / "nope"), "--bag", bag, "--out", str(tmp_path / "m.json")]) == 1
    err = capsys.readouterr().err
    assert "model directory not found" in err and err.count("\n") == 1
    assert main(["train", "--bag", bag, "--learner", "lwpr", "--out", str(tmp_path / "m"), "--jobs", "0"]) == 1
    assert "--jobs" in capsys.readouterr().err
    assert main(["train", "--bag", str(tmp_path / "missing_bag"), "--learner", "lwpr", "--out",
                 str(tmp_path / "m")]) == 1
    assert not os.path.exists(tmp_path / "m")
