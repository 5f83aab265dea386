"""The command line: global options before or after the verb, --feet in both spellings, help with examples."""
import pytest

from ciml_learning.cli import build_parser, main, profile_from_args, robot_from_args

HYQ_FEET = ["lf_foot", "lh_foot", "rf_foot", "rh_foot"]


def _parse(argv):
    from ciml_learning.cli import _join_feet

    p = build_parser()
    return p.parse_args(_join_feet(argv, {"extract", "diagnose", "train", "inspect"}))


@pytest.mark.parametrize("argv", [
    ["--feet", *HYQ_FEET, "extract", "--bag", "b", "--out", "o.npz"],
    ["--feet", ",".join(HYQ_FEET), "extract", "--bag", "b", "--out", "o.npz"],
    ["extract", "--bag", "b", "--out", "o.npz", "--feet", *HYQ_FEET],
    ["extract", "--feet", ",".join(HYQ_FEET), "--bag", "b", "--out", "o.npz"],
])
def test_feet_before_or_after_the_verb_in_either_spelling(argv):
    args = _parse(argv)
    assert args.verb == "extract" and args.feet == HYQ_FEET and args.bag == ["b"]


def test_robot_and_urdf_after_the_verb_and_before_it_are_kept(tmp_path):
    from ciml_learning.profile import shipped_profile

    go1 = shipped_profile("go1")
    for argv in (["--robot", go1, "diagnose", "--bag", "b", "--out", "d"],
                 ["diagnose", "--bag", "b", "--out", "d", "--robot", go1]):
        args = _parse(argv)
        assert args.robot == go1
        assert robot_from_args(args).foot_frames == ("FL_foot", "FR_foot", "RL_foot", "RR_foot")
        assert profile_from_args(args).inputs["base"] == {"estimate": "imu_legs"}
    args = _parse(["train", "--bag", "b", "--learner", "lwpr", "--out", "m"])
    assert args.robot is None and profile_from_args(args).name == "hyq"


# record (registered by ciml_sim): test/test_cli_registry.py
@pytest.mark.parametrize("verb", ["extract", "train", "evaluate", "diagnose", "inspect", "play"])
def test_each_verb_help_says_what_the_input_holds_and_shows_an_example(verb, capsys):
    with pytest.raises(SystemExit):
        main([verb, "--help"])
    out = capsys.readouterr().out
    assert "example: ciml " in out and "--robot" in out
    if verb in ("extract", "train", "diagnose"):
        assert "joint states" in out and "ROBOT_PROFILE.md" in out


def test_bad_profile_is_a_one_line_error(tmp_path, capsys):
    bad = tmp_path / "r.yaml"
    bad.write_text("format: 1\nname: x\nurdf: nope.urdf\n")
    assert main(["extract", "--robot", str(bad), "--bag", str(tmp_path), "--out", str(tmp_path / "t.npz")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "urdf: file not found" in err[0]
