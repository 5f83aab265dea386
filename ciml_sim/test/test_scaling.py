"""The scaling benchmark (`ciml bench --only scaling`, ciml_sim.scaling): the bag plan of a size,
the power-law fit, and a tiny end-to-end run (extraction and LWPR training, each in its own
process) whose numbers are positive and finite with every exponent field present."""
from __future__ import annotations

import math

import numpy as np
import pytest

from ciml_sim import benchmarks
from ciml_sim.scaling import FIT_KEYS, bag_plan, power_fit, scaling_benchmark


def test_bag_plan_shares_full_bags_and_records_the_remainder_with_its_own_seed():
    assert bag_plan(25_000, 10_000) == [(10_000, 0), (10_000, 1), (5_000, 1_005_000)]
    assert bag_plan(20_000, 10_000) == [(10_000, 0), (10_000, 1)]
    assert bag_plan(2_000, 10_000) == [(2_000, 1_002_000)]
    assert sum(k for k, _ in bag_plan(1_000_000, 10_000)) == 1_000_000
    with pytest.raises(ValueError):
        bag_plan(0, 10_000)


def test_power_fit_recovers_an_exponent_and_refuses_what_it_cannot_fit():
    n = np.array([1e4, 3e4, 1e5, 1e6])
    fit = power_fit(n, 2e-3 * n ** 1.5)
    assert fit is not None and fit["b"] == pytest.approx(1.5, abs=1e-3) and fit["a"] == pytest.approx(2e-3, rel=1e-3)
    assert power_fit([1e4], [1.0]) is None
    assert power_fit([1e4, 2e4], [1.0, 0.0]) is None


def test_the_benchmark_entry_point_passes_string_settings():
    import inspect

    params = inspect.signature(benchmarks.scaling).parameters
    assert {"sizes", "stages", "bag_samples", "jobs", "stage_limit_s", "bag_dir"} <= set(params)
    assert all(p.default is not p.empty for p in params.values())


def test_tiny_scaling_run_measures_each_stage_and_size():
    sizes = (2_000, 4_000)
    r = scaling_benchmark(",".join(map(str, sizes)), "extraction,train_lwpr")
    assert r["sizes"] == list(sizes) and "simulator" in r["data"] and r["failed"] == [] and r["skipped"] == []
    assert r["data_recording_s"] > 0
    for stage in ("extraction", "train_lwpr"):
        s = r["stages"][stage]
        assert [run["samples"] for run in s["runs"]] == list(sizes)
        for run in s["runs"]:
            for key in ("wall_s", "cpu_s", "peak_rss_mb", "rss_before_mb", "us_per_sample", "import_s"):
                assert math.isfinite(run[key]) and run[key] > 0, (stage, key, run)
            assert run["peak_rss_mb"] >= run["rss_before_mb"]
            assert 0 < run["valid_samples"] <= run["log_samples"] <= run["samples"]
        for name in FIT_KEYS.values():
            assert f"{name}_exponent" in s and f"{name}_coefficient" in s
        assert math.isfinite(s["time_exponent"]) and math.isfinite(s["rss_exponent"])
        assert set(s["us_per_sample"]) == {str(n) for n in sizes}
