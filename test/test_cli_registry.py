"""`ciml` verbs and `ciml bench` benchmarks are registered by the package that implements them
(entry point groups `ciml.verbs` and `ciml.benchmarks`, docs/ARCHITECTURE.md §3-4): every verb
of the command list is there, each registered where it lives, a package installed alone runs its
own verbs, and a broken registration costs only its own verb."""
from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys
from importlib.metadata import entry_points

import pytest

from ciml_learning.cli.args import Verb
from ciml_learning.cli.main import VERB_GROUP, build_parser, installed_verbs, main

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# docs/ARCHITECTURE.md §4 and the README's command list, in `ciml --help` order
VERBS = ["record", "extract", "train", "evaluate", "export-mjcf", "closed-loop", "diagnose", "verify", "gap-bench",
         "play", "bench", "launch", "inspect"]
BENCHMARKS = {
    "ciml_learning": ["extraction_batching", "extraction_throughput", "lwpr_cross_2d", "lwpr_online_30dims",
                      "online_nodes_per_sample", "train_lwpr_paper_size", "train_sgpr_paper_size"],
    "ciml_control": ["id_controller_dds_latency", "id_controller_step"],
    "ciml_sim": ["diagnosis_50k", "live_graph_memory", "live_graph_rates", "live_online_learning", "scaling",
                 "sim_bridge_rate", "sim_headless_speed"],
}


def _package(dist) -> str:
    return dist.name.replace("-", "_")


def test_every_verb_is_installed_in_its_order_and_registered_where_it_is_implemented():
    verbs = installed_verbs()
    assert [name for name, _ in verbs] == VERBS
    for ep in entry_points(group=VERB_GROUP):
        verb = ep.load()
        assert isinstance(verb, Verb)
        owner = _package(ep.dist)
        # the registration, the verb's options and its implementation are all in the registering package
        assert ep.module.split(".")[0] == owner, ep
        assert verb.run.split(".")[0] == owner and ":" in verb.run, (ep.name, verb.run)
        module, _, function = verb.run.partition(":")
        assert callable(getattr(__import__(module, fromlist=[function]), function)), verb.run


@pytest.mark.parametrize("verb", ["record"])
def test_simulator_verb_help_shows_an_example(verb, capsys):
    """(the `record` case of ciml_learning/test/test_cli_args.py, here because ciml_sim registers it)"""
    with pytest.raises(SystemExit):
        main([verb, "--help"])
    out = capsys.readouterr().out
    assert "example: ciml " in out and "--robot" in out


def test_every_benchmark_is_registered_by_its_package_and_runs_without_arguments():
    from ciml_learning.cli.bench import installed_benchmarks

    found = installed_benchmarks()
    assert sorted(found) == sorted(n for names in BENCHMARKS.values() for n in names)
    for name, ep in found.items():
        owner = _package(ep.dist)
        home = "ciml_learning.cli" if owner == "ciml_learning" else owner  # ciml_learning's verbs and benchmarks: cli/
        assert name in BENCHMARKS[owner] and ep.module == f"{home}.benchmarks", (name, ep.value)
        fn = ep.load()
        required = [p for p in inspect.signature(fn).parameters.values() if p.default is p.empty]
        assert not required, (name, required)


# A process in which only ciml_learning is installed: importing ciml_control or ciml_sim fails, and
# their entry points are not listed (as with `colcon build --packages-select ciml_learning`).
_ALONE = r"""
import importlib.abc, importlib.metadata, json, sys

class Absent(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("ciml_control", "ciml_sim"):
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, Absent())
_all = importlib.metadata.entry_points
def alone(**kw):
    eps = _all(**kw)
    return type(eps)(ep for ep in eps if ep.dist is None or ep.dist.name.replace("-", "_") == "ciml_learning")
importlib.metadata.entry_points = alone

from ciml_learning.cli.main import main
rc = main(sys.argv[1:])
print(json.dumps({"rc": rc, "sim_loaded": any(m.split(".")[0] in ("ciml_control", "ciml_sim") for m in sys.modules)}))
"""


def _alone(tmp_path, *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _ALONE, *argv], capture_output=True, text=True, timeout=600,
                          cwd=tmp_path)


def test_ciml_learning_installed_alone_runs_its_own_verbs(tmp_path):
    help_ = _alone(tmp_path, "--help")
    assert help_.returncode == 0, help_.stderr
    listed = [line.split()[0] for line in help_.stdout.split("VERB\n", 1)[1].split("\noptions:")[0].splitlines()
              if line.startswith("    ") and not line.startswith("      ")]
    assert listed == [v for v in VERBS if v not in ("record", "export-mjcf", "closed-loop", "verify", "gap-bench")]
    assert "ciml: note" not in help_.stderr
    # a real verb end to end: extract on a shipped bag, with neither upper package importable
    out = tmp_path / "targets.npz"
    run = _alone(tmp_path, "extract", "--bag", os.path.join(ROOT, "bags", "nominal_stand"), "--out", str(out))
    assert run.returncode == 0, run.stderr
    status = json.loads(run.stdout.strip().splitlines()[-1])
    assert status == {"rc": 0, "sim_loaded": False} and out.is_file()
    # an upper package's verb is simply not offered
    rec = _alone(tmp_path, "record", "--scenario", "nominal", "--motion", "trot_35", "--out", "b")
    assert rec.returncode == 2 and "invalid choice: 'record'" in rec.stderr


def test_a_broken_registration_costs_only_its_own_verb(monkeypatch, capsys):
    import importlib.metadata as md

    real = md.entry_points
    broken = md.EntryPoint(name="broken", value="no_such_package.verbs:BROKEN", group=VERB_GROUP)
    not_a_verb = md.EntryPoint(name="odd", value="json:dumps", group=VERB_GROUP)
    twice = md.EntryPoint(name="extract", value="ciml_sim.verbs:RECORD", group=VERB_GROUP)

    def patched(**kw):
        eps = real(**kw)
        return type(eps)([*eps, broken, not_a_verb, twice]) if kw.get("group") == VERB_GROUP else eps

    monkeypatch.setattr(md, "entry_points", patched)
    args = build_parser().parse_args(["extract", "--bag", "b", "--out", "t.npz"])
    assert args.verb == "extract" and args.out == "t.npz"
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and all(line.startswith("ciml: note: verb ") for line in err), err
    assert "broken" in err[0] and "ModuleNotFoundError" in err[0]
    assert "odd" in err[1] and "extract registered twice" in err[2]
