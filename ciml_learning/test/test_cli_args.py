"""The command line: global options before or after the verb, --feet in both spellings, help with examples."""
import os

import pytest

from ciml_learning.cli.main import build_parser, main, profile_from_args, robot_from_args

HYQ_FEET = ["lf_foot", "lh_foot", "rf_foot", "rh_foot"]


def _parse(argv):
    from ciml_learning.cli.main import _join_feet

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
    from ciml_learning.core.profile import shipped_profile

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


# --- every verb honours the robot options or refuses them (never ignores them) -------------


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


@pytest.mark.parametrize("argv", [
    ["launch", "--print", "ciml_sim", "closed_loop.launch.yaml"],
    ["extract", "--bag", "b", "--out", "o.npz"],
    ["inspect", "--bag", "b"],
    ["play", "--bag", "b"],
    ["bench", "--out", "b.json"],
])
def test_a_missing_profile_is_a_one_line_error_for_every_verb(argv, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["--robot", "does_not_exist.yaml", *argv]) == 1
    msg = _one_line_error(capsys)
    assert ("does_not_exist.yaml: file not found" in msg) != ("--robot not taken by" in msg)


@pytest.mark.parametrize("verb, argv", [
    ("play", ["--bag", "b"]), ("bench", ["--out", "b.json"]), ("gap-bench", ["--out", "g"]),
])
@pytest.mark.parametrize("option", [["--robot", "go1"], ["--urdf", "u.urdf"], ["--feet", "a,b,c,d"]])
def test_verbs_without_a_robot_refuse_the_robot_options(verb, argv, option, capsys):
    from ciml_learning.cli.main import installed_verbs

    if verb not in dict(installed_verbs()):
        pytest.skip(f"{verb} not installed")
    for order in ([*option, verb, *argv], [verb, *argv, *option]):
        assert main(order) == 1
        msg = _one_line_error(capsys)
        assert f"{option[0]} not taken by {verb}:" in msg


def test_shipped_robot_names_and_erd_urdfs_are_accepted(tmp_path, monkeypatch):
    from ciml_learning.core.profile import ProfileError, load_profile, shipped_names, with_overrides

    assert {"hyq", "go1", "solo12", "a1"} <= set(shipped_names())
    for name in shipped_names():
        args = _parse(["--robot", name, "train", "--bag", "b", "--learner", "lwpr", "--out", "m"])
        assert profile_from_args(args).name == name
    monkeypatch.chdir(tmp_path)
    (tmp_path / "go1").write_text("format: 1\n")   # a file of that name wins over the shipped profile
    with pytest.raises(ProfileError, match="^profile go1: name: "):
        load_profile("go1")
    prof = with_overrides(load_profile("hyq"), "erd:go1_description/urdf/go1.urdf",
                          ["FL_foot", "FR_foot", "RL_foot", "RR_foot"])
    assert prof.urdf.endswith("go1_description/urdf/go1.urdf") and prof.robot().n_joints == 12
    with pytest.raises(ProfileError, match="--urdf: file not found: .*nope.urdf"):
        with_overrides(load_profile("hyq"), "erd:nope.urdf")


def _launch_file(tmp_path, declares: tuple[str, ...]):
    """A launch file of one node of an ament prefix 'fake' whose parameters echo its arguments."""
    prefix = tmp_path / "prefix"
    (prefix / "share" / "ament_index" / "resource_index" / "packages").mkdir(parents=True)
    (prefix / "share" / "ament_index" / "resource_index" / "packages" / "fake").write_text("")
    (prefix / "lib" / "fake").mkdir(parents=True)
    (prefix / "lib" / "fake" / "node").write_text("#!/bin/sh\n")
    (prefix / "lib" / "fake" / "node").chmod(0o755)
    lines = ["launch:"] + [f"- arg: {{name: {a}, default: ''}}" for a in declares]
    params = ", ".join(f"{{name: {a}, value: '$(var {a})'}}" for a in declares)
    lines.append(f"- node: {{pkg: fake, exec: node, name: n, param: [{params}]}}")
    path = tmp_path / "t.launch.yaml"
    path.write_text("\n".join(lines) + "\n")
    return str(path), str(prefix)


def test_launch_passes_the_robot_as_the_files_robot_argument(tmp_path, monkeypatch, capsys):
    from ciml_learning.core.profile import shipped_profile

    path, prefix = _launch_file(tmp_path, ("robot", "urdf"))
    monkeypatch.setenv("AMENT_PREFIX_PATH", prefix)
    assert main(["--robot", "go1", "launch", "--print", path]) == 0
    assert "robot:=go1" in capsys.readouterr().out
    assert main(["launch", "--print", path, "--robot", shipped_profile("solo12")]) == 0
    assert f"robot:={shipped_profile('solo12')}" in capsys.readouterr().out
    assert main(["--urdf", "erd:go1_description/urdf/go1.urdf", "launch", "--print", path]) == 0
    assert "go1_description/urdf/go1.urdf" in capsys.readouterr().out
    assert main(["--robot", "go1", "launch", "--print", path, "robot:=hyq"]) == 1
    assert "both given" in _one_line_error(capsys)
    assert main(["--feet", "a,b,c,d", "launch", "--print", path]) == 1   # the file declares no feet
    assert "declares no launch argument 'feet'" in _one_line_error(capsys)


def test_launch_refuses_a_robot_its_file_cannot_take(tmp_path, monkeypatch, capsys):
    path, prefix = _launch_file(tmp_path, ("motion",))
    monkeypatch.setenv("AMENT_PREFIX_PATH", prefix)
    assert main(["--robot", "go1", "launch", "--print", path]) == 1
    msg = _one_line_error(capsys)
    assert "declares no launch argument 'robot'" in msg and "declared: motion" in msg


def test_version_names_the_package_version_and_the_commit(capsys):
    import subprocess

    from ciml_learning.core.version import package_version

    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    out = capsys.readouterr().out.strip()
    head = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                          cwd=os.path.dirname(__file__)).stdout.strip()
    assert out.startswith(f"ciml {package_version()} (commit {head}") and package_version() != "unknown", out
