"""How steady is the 5 s RMS feedback effort under one model? Nominal controller, trot_35 120 s,
seed 11: the 5 s after an instant over the 5 s before (the rollback's "worse" test), at instants
1 s apart.

    python effort_noise.py   → effort_noise_output.txt
"""
import numpy as np

from ciml_learning.core.profile import load_profile, profile_path
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

for spec, scenario in (("go1", "go1_gap"), ("hyq", "default_gap")):
    robot = load_profile(profile_path(spec)).robot()
    run = run_headless(robot, resolve_scenario(scenario, robot), "trot_35", 120.0, 11, progress=False)
    e = np.asarray(run.feedback_effort, float)
    fs = len(e) / 120.0
    w = int(5 * fs)
    cumulative = np.concatenate([[0.0], np.cumsum(e * e)])
    at = np.arange(w + int(10 * fs), len(e) - w, int(fs))
    ratio = np.sqrt(cumulative[at + w] - cumulative[at]) / np.sqrt(cumulative[at] - cumulative[at - w])
    p50, p95, p99, top = np.percentile(ratio, [50, 95, 99, 100])
    print(f"{spec} {fs:.0f} Hz 5 s after / 5 s before: p50 {p50:.3f} p95 {p95:.3f} p99 {p99:.3f} "
          f"max {top:.3f} share > 1.08: {np.mean(ratio > 1.08):.3f}", flush=True)
