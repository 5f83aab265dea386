"""Every `ciml` verb × its numeric, path and enum arguments × hostile values: exit 1 (CimlError)
or 2 (argparse), one line on stderr, never a traceback or an internal error.

Each case changes one argument of an invocation whose other arguments are valid but
whose bag (or motion, or case number) is missing, so no verb does real work: a value
that passes its own check still ends in a one-line refusal a moment later.
"""
from __future__ import annotations

import os

import pytest

from ciml_learning.cli.main import main

NON_UTF8 = os.fsdecode(b"bad\xff\xfename")
NUMBERS = ["-1", "0", "1e308", "99999999999999999999999", "nan", "inf", "", "abc"]


def paths(tmp) -> list[str]:
    full = tmp / "full_dir"
    full.mkdir(exist_ok=True)
    (full / "user_file.txt").write_text("not CIML's")
    return ["", str(tmp), str(full), "/proc/nope/x.json", "/dev/null", NON_UTF8, "/", "a" * 5000]


ENUMS = ["", "nope", NON_UTF8, "-1"]

# verb: (valid base arguments, {argument: kind})
VERBS: dict[str, tuple[list[str], dict[str, str]]] = {
    "record": (["--scenario", "nominal", "--motion", "no_such_motion", "--duration", "1", "--seed", "0",
                "--out", "{tmp}/new_bag"],
               {"--scenario": "path", "--motion": "enum", "--duration": "number", "--seed": "number",
                "--out": "path"}),
    "extract": (["--bag", "{tmp}/missing_bag", "--out", "{tmp}/t.npz"], {"--bag": "path", "--out": "path"}),
    "train": (["--bag", "{tmp}/missing_bag", "--learner", "lwpr", "--out", "{tmp}/model", "--jobs", "1"],
              {"--bag": "path", "--learner": "enum", "--out": "path", "--jobs": "number"}),
    "evaluate": (["--model", "{tmp}/missing_model", "--bag", "{tmp}/missing_bag", "--out", "{tmp}/m.json"],
                 {"--model": "path", "--bag": "path", "--out": "path"}),
    "closed-loop": (["--scenario", "nominal", "--motion", "no_such_motion", "--model", "nominal",
                     "--duration", "1", "--seed", "0", "--out", "{tmp}/r.json"],
                    {"--scenario": "path", "--motion": "enum", "--model": "path", "--duration": "number",
                     "--seed": "number", "--out": "path", "--report": "path"}),
    "diagnose": (["--bag", "{tmp}/missing_bag", "--out", "{tmp}/diag"],
                 {"--bag": "path", "--heldout": "path", "--out": "path"}),
    "export-mjcf": (["--diagnosis", "{tmp}/missing_diag", "--mjcf", "{tmp}/missing.xml", "--out", "{tmp}/p.xml"],
                    {"--diagnosis": "path", "--mjcf": "path", "--out": "path"}),
    "gap-bench": (["--out", "{tmp}/gb", "--cases", "9999", "--jobs", "1", "--scale", "1"],
                  {"--out": "path", "--cases": "number", "--jobs": "number", "--scale": "number"}),
    "play": (["--bag", "{tmp}/missing_bag", "--rate", "1"], {"--bag": "path", "--rate": "number"}),
    "bench": (["--out", "{tmp}/bench.json", "--only", "no_such_benchmark"], {"--out": "path", "--only": "enum"}),
    "inspect": (["--bag", "{tmp}/missing_bag", "--out", "{tmp}/profile.yaml"], {"--bag": "path", "--out": "path"}),
    "launch": (["{tmp}/missing.launch.yaml", "--stop-timeout", "1"], {"FILE": "path", "--stop-timeout": "number"}),
}


def cases():
    for verb, (_, args) in VERBS.items():
        for arg, kind in args.items():
            n = {"number": len(NUMBERS), "enum": len(ENUMS), "path": 8}[kind]
            for i in range(n):
                yield pytest.param(verb, arg, kind, i, id=f"{verb}{arg}-{kind}{i}")


def _with(base: list[str], arg: str, value: str) -> list[str]:
    out = list(base)
    if arg == "FILE":  # the positional argument comes first
        return [value, *out[1:]]
    if arg in out:
        out[out.index(arg) + 1] = value
    else:
        out += [arg, value]
    return out


@pytest.mark.parametrize("verb,arg,kind,i", list(cases()))
def test_hostile_argument_gives_one_line(verb, arg, kind, i, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("CIML_DEBUG", raising=False)
    hostile_paths = paths(tmp_path)
    value = {"number": NUMBERS, "enum": ENUMS, "path": hostile_paths}[kind][i]
    base = [a.replace("{tmp}", str(tmp_path)) for a in VERBS[verb][0]]
    argv = [verb, *_with(base, arg, value)]
    try:
        rc = main(argv)
    except SystemExit as exc:  # argparse
        rc = exc.code
    err = capsys.readouterr().err
    lines = [ln for ln in err.replace("\r", "\n").splitlines()
             if ln.strip() and not ln.startswith(("ciml: note:", "["))]
    assert rc in (1, 2), (argv, rc, err)
    assert "Traceback" not in err and "internal error" not in err, err
    assert len(lines) == 1 and lines[-1].startswith(f"ciml {verb}: error:"), err
    # nothing outside tmp was replaced and nothing half-made was left behind
    assert os.path.exists("/dev/null") and not os.path.isfile("/dev/null")
    assert (tmp_path / "full_dir" / "user_file.txt").read_text() == "not CIML's"


def test_jobs_are_capped_at_the_available_cores(capsys):
    from ciml_learning.cli.args import available_cores, cap_jobs

    cores = available_cores()
    assert cap_jobs(10_000) == cores and f"capped at the {cores} available cores" in capsys.readouterr().err
    assert cap_jobs(-1) == cores and cap_jobs(1) == 1 and capsys.readouterr().err == ""


def test_bag_without_metadata_names_what_is_missing(tmp_path, capsys):
    import shutil

    bag = tmp_path / "bag"
    shutil.copytree(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "bags", "nominal_stand"),
                    bag)
    (bag / "metadata.yaml").unlink()
    assert main(["extract", "--bag", str(bag), "--out", str(tmp_path / "t.npz")]) == 1
    err = capsys.readouterr().err.strip()
    assert "metadata.yaml is missing" in err and "None" not in err and err.count("\n") == 0


@pytest.mark.parametrize("option", ["seeds=x1", "baseline_seeds=1,,2", "seeds=1.5"])
def test_bench_seed_options_that_are_not_integers_give_one_line(option, tmp_path, capsys, monkeypatch):
    """Checked before any graph starts: nothing is written."""
    monkeypatch.delenv("CIML_DEBUG", raising=False)
    out = tmp_path / "bench.json"
    assert main(["bench", "--only", "live_online_learning", "--set", option, "--out", str(out)]) == 1
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip() and not ln.startswith("[")]
    assert len(err) == 1 and err[0].startswith("ciml bench: error: ") and "integers or none" in err[0], err
    assert not out.exists()
