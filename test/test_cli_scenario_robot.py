"""A scenario of another robot names the --robot to give (the simulator's verbs, through the CLI)."""
import pytest

from ciml_learning.cli.main import main


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("verb", [["record", "--duration", "1"], ["closed-loop", "--model", "nominal"]])
def test_a_scenario_of_another_robot_names_the_robot_to_give(verb, tmp_path, capsys):
    """go1_gap names go1's joints: on the default robot (HyQ) the error says which --robot fits."""
    out = str(tmp_path / "out")
    assert main([*verb, "--scenario", "go1_gap", "--motion", "trot_35", "--out", out]) == 1
    msg = _one_line_error(capsys)
    assert "unknown joint 'FL_calf_joint'" in msg and msg.endswith("add --robot go1")
    assert main(["--robot", "go1", *verb, "--scenario", "default_gap", "--motion", "trot_35", "--out", out]) == 1
    assert _one_line_error(capsys).endswith("is for robot hyq: add --robot hyq")
