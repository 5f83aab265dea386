"""The randomised gap-bench (issue 31): the draw's reproducibility, the scorer on hand-made diagnoses,
the pictures, and the Dask path equal to the local one."""
from __future__ import annotations

import argparse
import json
import os

import numpy as np
import pytest

from ciml_learning.core.errors import CimlError
from ciml_learning.core.robot import load_robot
from ciml_learning.effects import CATALOGUE, EFFECTS, OUT_OF_CATALOGUE, draws
from ciml_learning.learning import cluster
from ciml_sim import gapbench, gapplots, gaprandom, gapstats
from ciml_sim.scenario import parse_scenario

JOINTS = load_robot().joint_names


def test_draw_is_reproducible_from_the_seed_and_each_case_a_valid_scenario():
    a, b = gaprandom.draw(12, 5), gaprandom.draw(12, 5)
    assert json.dumps(a) == json.dumps(b)
    assert json.dumps(gaprandom.draw(4, 5)) == json.dumps(a[:4])  # case i depends on (seed, i) only
    assert json.dumps(gaprandom.draw(12, 6)) != json.dumps(a)
    robot = load_robot()
    for i, spec in enumerate(a):
        parse_scenario({"name": f"case_{i}", **gapbench.scenario_of(spec)}, robot)
        assert 0 <= len(spec["effects"]) <= 3
        assert set(spec) == set(gaprandom.CASE_FIELDS)
        assert not {m for m, _ in spec["train_motions"]} & {m for m, _ in spec["heldout_motions"]}


def test_draws_hold_every_kind_and_type_inside_the_physical_bounds():
    specs = gaprandom.draw(300, 1)
    kinds = {s["kind"] for s in specs}
    assert kinds == {"nominal", "catalogue", "out_of_catalogue"}
    types = {e["type"] for s in specs for e in s["effects"]}
    assert set(CATALOGUE) | set(OUT_OF_CATALOGUE) == types
    assert all(not s["effects"] for s in specs if s["kind"] == "nominal")
    robot = load_robot()
    for s in specs:
        places = [e.get("joint") or e.get("link") for e in s["effects"]]
        assert len([p for p in places if p]) == len({p for p in places if p})  # one effect per place
        for e in s["effects"]:
            ranges = EFFECTS[e["type"]].physical_range(robot) if e["type"] in CATALOGUE else {}
            for k, r in ranges.items():
                if k in e and isinstance(r, list):
                    assert r[0] <= e[k] <= r[1], (e, k, r)
            assert draws.effect_size(e) > 0


def test_a_draw_range_outside_its_field_is_refused(monkeypatch):
    monkeypatch.setitem(draws.DRAW_RANGES, "torque_offset", {"value": (0.3, 500.0)})
    with pytest.raises(draws.DrawError, match="torque_offset.value"):
        gaprandom.draw(2, 0)


def _effect(type_, where, params, std, share=0.5):
    return {"type": type_, **where, "params": params, "std": std, "share": share}


def _scored(spec, diagnosis):
    s = gapbench.score_case(spec["effects"], diagnosis, JOINTS)
    return gaprandom.score_random_case(spec, s, diagnosis)


def known_cases() -> list[dict]:
    """Five hand-made cases with a known score (see test_scorer_on_known_cases)."""
    coulomb = {"type": "joint_coulomb_friction", "joint": "rf_kfe_joint", "value": 6.0}
    gain = {"type": "torque_gain", "joint": "lf_haa_joint", "value": 0.8}
    spring = {"type": "joint_spring", "joint": "lh_hfe_joint", "stiffness": 80.0, "rest": 0.0}
    base = {"unexplained_share": 0.05, "shrink": {"ratio": 0.8}, "localization": []}
    return [
        # friction right, 0.5 std off (inside 50 %), gain missed: a payload named instead
        _scored({"kind": "catalogue", "effects": [coulomb, gain]},
                {**base, "effects": [_effect("joint_coulomb_friction", {"joint": "rf_kfe_joint"}, {"value": 6.5},
                                             {"value": 1.0}),
                                     _effect("payload", {}, {"mass": 1.0, "com": [0, 0, 0]},
                                             {"mass": 0.1, "com": [1, 1, 1]}, 0.3)]}),
        # friction right, 1.5 std off (outside 68 %, inside 95 %)
        _scored({"kind": "catalogue", "effects": [dict(coulomb, value=3.0)]},
                {**base, "effects": [_effect("joint_coulomb_friction", {"joint": "rf_kfe_joint"}, {"value": 4.5},
                                             {"value": 1.0})]}),
        _scored({"kind": "nominal", "effects": []}, {**base, "effects": []}),
        _scored({"kind": "nominal", "effects": []},
                {**base, "effects": [_effect("encoder_offset", {"joint": "rf_hfe_joint"}, {"value": 0.001},
                                             {"value": 0.001}, 0.2)]}),
        _scored({"kind": "out_of_catalogue", "effects": [spring]},
                {**base, "unexplained_share": 0.9, "effects": [],
                 "unexplained_localised": [{"joint": "lh_hfe_joint", "share": 0.9}]}),
    ]


def test_scorer_on_known_cases():
    s = gapstats.summarise_random(known_cases())
    assert s["kinds"] == {"catalogue": 2, "nominal": 2, "out_of_catalogue": 1}
    assert (s["named_right"]["k"], s["named_right"]["n"]) == (2, 3)
    assert (s["false_positive_nominal"]["k"], s["false_positive_nominal"]["n"]) == (1, 2)
    assert s["out_of_catalogue_unexplained_and_localised"]["k"] == 1
    assert s["confusion"] == {"joint_coulomb_friction": {"joint_coulomb_friction": 2},
                              "torque_gain": {"payload": 1},
                              gapstats.NOMINAL_ROW: {"nothing": 1, "encoder_offset": 1},
                              "joint_spring": {"unexplained": 1}}
    cal = s["calibration"]  # the two scored parameters are 0.5 and 1.5 std off; z90 = 1.64
    assert [cal[p]["k"] for p in ("0.50", "0.68", "0.90", "0.95", "0.99")] == [1, 1, 2, 2, 2]  # z 0.67 … 2.58
    assert cal["0.95"]["n"] == 2
    assert s["per_type"]["torque_gain"]["named_right"]["k"] == 0
    assert s["median_param_rel_error"] == pytest.approx(np.median([0.5 / 6, 1.5 / 3]))
    assert s["per_type"]["joint_coulomb_friction"]["detection_limit"]["limit"] is None  # 2 draws only


def test_wilson_interval_of_a_rate():
    r = gapstats.rate(1, 2)
    assert r["fraction"] == 0.5
    assert r["ci95"] == pytest.approx([0.0945, 0.9055], abs=1e-4)
    assert gapstats.rate(0, 0)["fraction"] is None


def test_detection_limit_from_draws():
    sizes = np.linspace(0.5, 15.0, 30)
    lim = gapstats.detection_limit([(x, bool(x >= 5.0)) for x in sizes])
    assert lim["limit"] == pytest.approx(4.5)  # one miss (4.5) in the ten draws from it on is 90 %
    assert lim["named_right_above"]["k"] == 21 and lim["draws_above"] == 22
    # two misses among ten larger draws (8.0, 8.5) move the limit up to the last window holding one
    assert gapstats.detection_limit([(x, bool(x >= 5.0 and x not in (8.0, 8.5))) for x in sizes])["limit"] == 8.5
    assert "too few" in gapstats.detection_limit([(1.0, True)] * 3)["why"]
    assert "not reached" in gapstats.detection_limit([(x, i % 2 == 0) for i, x in enumerate(sizes)])["why"]


def test_report_has_the_plots_and_the_tables(tmp_path):
    cases = known_cases()
    specs = [{"effects": c["effects_true"] if "effects_true" in c else []} for c in cases]
    for i, c in enumerate(cases, start=1):
        c.update(case=i, effects_true=[])
    doc = gaprandom.write(str(tmp_path), len(cases), 0, specs, list(cases), {"engine": "test", "wall_s": 0})
    for name in gapplots.PLOTS:
        with open(tmp_path / name, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"
    page = (tmp_path / "report.html").read_text()
    assert all(n in page for n in gapplots.PLOTS) and "gap_bench.json" in page
    assert not doc["partial"]
    assert json.loads((tmp_path / "gap_bench.json").read_text())["summary"]["named_right"]["k"] == 2


@pytest.mark.filterwarnings("error::UserWarning")
def test_confusion_plot_of_no_scored_case_draws_without_a_singular_axis():
    """A partial bench with no case scored yet still writes its confusion plot (matplotlib warns
    of identical axis limits for an empty image: made an error here)."""
    import matplotlib

    matplotlib.use("Agg")
    assert gapplots.confusion_figure({}).axes[0].texts[0].get_text() == "no case scored"


def test_cluster_address_parsing():
    assert cluster.parse_cluster("local:2") == "local:2"
    assert cluster.parse_cluster("tcp://10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    for bad in ("local:0", "local:x", "nohost", "host:port"):
        with pytest.raises(argparse.ArgumentTypeError):
            cluster.parse_cluster(bad)


def test_unreachable_scheduler_is_a_one_line_error(monkeypatch):
    monkeypatch.setattr(cluster, "CONNECT_TIMEOUT", 2.0)
    with pytest.raises(cluster.ClusterError, match="no Dask scheduler answers") as err:
        cluster.run_all(gapstats.summarise_random, [[]], cluster="tcp://127.0.0.1:9")
    assert "\n" not in str(err.value)


def test_local_cluster_gives_the_local_results():
    """The scorer's work on a LocalCluster (2 processes on 127.0.0.1) equals joblib's, in order."""
    items = [known_cases(), known_cases()[:2], known_cases()[2:]]
    local = cluster.run_all(gapstats.summarise_random, items, jobs=1)
    remote = cluster.run_all(gapstats.summarise_random, items, cluster="local:2", module="ciml_sim.gapstats")
    assert json.dumps(remote, sort_keys=True) == json.dumps(local, sort_keys=True)


@pytest.mark.slow
def test_a_worker_without_the_project_is_a_one_line_error():
    with cluster.dask_client("local:1") as client, pytest.raises(cluster.ClusterError, match="cannot import") as err:
        cluster.check_workers(client, "ciml_no_such_package")
    assert "\n" not in str(err.value) and "install the project" in str(err.value)


def assert_same_scores(a, b, path="cases"):
    """Equal names, counts and flags; floats equal to 1e-9 relative. Dask's nanny runs its workers (and
    so each case's processes) with one BLAS thread (OMP_NUM_THREADS=1), so sums can differ in the last
    bits: measured 1e-12 relative on the bags' and the diagnosis' numbers. Timings ("*_s") differ."""
    if isinstance(a, dict):
        assert set(a) == set(b), path
        for k in a:
            if not k.endswith("_s"):
                assert_same_scores(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same_scores(x, y, f"{path}[{i}]")
    elif isinstance(a, float) and isinstance(b, float):
        assert b == pytest.approx(a, rel=1e-9, abs=1e-12), path
    else:
        assert a == b, path


@pytest.mark.slow
def test_random_bench_on_a_local_cluster_equals_the_local_run(tmp_path):
    """Two short random cases recorded, diagnosed and scored with joblib and on a LocalCluster."""
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    local = gaprandom.random_bench(str(tmp_path / "local"), 2, 3, jobs=1, scale=0.2)
    remote = gaprandom.random_bench(str(tmp_path / "dask"), 2, 3, scale=0.2, cluster="local:2")
    assert remote["random"] == local["random"] and remote["engine"] == "local:2"
    assert_same_scores(local["cases"], remote["cases"])
    assert not remote["partial"] and remote["summary"]["failed_cases"] == 0


def test_rescore_reads_the_draw_and_marks_a_missing_case_partial(tmp_path):
    specs = gaprandom.draw(2, 5)
    (tmp_path / "draws.json").write_text(json.dumps({"n": 2, "seed": 5, "cases": specs}))
    truth = specs[0]["effects"]
    found = [{"type": e["type"], **{k: e[k] for k in ("joint", "joints", "link") if k in e},
              "params": {k: v for k, v in e.items() if k not in ("type", "joint", "joints", "link")},
              "std": {}, "share": 1.0 / len(truth)} for e in truth]
    (tmp_path / "case_01" / "diagnosis").mkdir(parents=True)
    (tmp_path / "case_01" / "diagnosis" / "diagnosis.json").write_text(
        json.dumps({"effects": found, "unexplained_share": 0.0, "shrink": {}, "localization": []}))
    doc = gaprandom.rescore(str(tmp_path))
    assert doc["partial"] and [c["case"] for c in doc["cases"]] == [1]
    assert doc["random"]["cases"] == specs
    assert all(r["type_right"] and r["location_right"] for r in doc["cases"][0]["effects"])
    assert json.loads((tmp_path / "gap_bench.json").read_text())["partial"] is True


def test_resume_keeps_the_finished_cases_and_runs_the_rest(tmp_path, monkeypatch):
    """An interrupted bench goes on where it stopped: a case with its score.json is not run again,
    one without is; another draw in the same folder is refused."""
    ran: list[int] = []

    def fake_case(index, spec, out_dir, scale):  # the recording and the diagnosis, in one line each
        ran.append(index)
        diag = os.path.join(out_dir, f"case_{index:02d}", "diagnosis")
        os.makedirs(diag, exist_ok=True)
        with open(os.path.join(diag, "diagnosis.json"), "w") as f:
            json.dump({"effects": [], "unexplained_share": 1.0}, f)
        return {"case": index, "effects_true": spec["effects"], "effects": [], "spurious": [], "record_s": 1.0}

    monkeypatch.setattr(gapbench, "run_case", fake_case)
    monkeypatch.setattr(gaprandom, "score_random_case", lambda spec, scored, diagnosis: dict(scored, kind=spec["kind"]))
    out = str(tmp_path / "bench")
    first = gaprandom.random_bench(out, 3, 9)
    assert ran == [1, 2, 3] and not first["partial"] and first["resumed_cases"] == 0
    os.remove(os.path.join(out, "case_02", gaprandom.SCORE_FILE))  # case 2 never finished
    ran.clear()
    again = gaprandom.random_bench(out, 3, 9, resume=True)
    assert ran == [2] and again["resumed_cases"] == 2
    assert [c["case"] for c in again["cases"]] == [1, 2, 3] and again["cases"] == first["cases"]
    with pytest.raises(CimlError, match="holds the draw of --random 3 --seed 9"):
        gaprandom.random_bench(out, 3, 10, resume=True)
    ran.clear()
    gaprandom.random_bench(out, 3, 9)  # without --resume every case runs again
    assert ran == [1, 2, 3]
