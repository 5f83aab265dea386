"""The learner A/B of the fourteenth session (results/LIVE_GRAPH.md): online-learning runs of the
shipped graph one after the other, per minute the effort and the learner's counters.
Run: python learner_ab.py SECONDS OUT.json (with the instant sampler's diff applied, whose launch
argument learner_cpu_budget 0.0 learns every instant)."""
import json
import sys
import time

from ciml_learning.core.profile import load_profile
from ciml_sim import live_bench

robot = load_profile("hyq").robot()
live_bench._private_domain()
duration, out = float(sys.argv[1]), sys.argv[2]
variants = [("sampler", {"online_learning": "true", "seed": "51"}),
            ("every_instant", {"online_learning": "true", "seed": "51", "learner_cpu_budget": "0.0"})]
result: dict = {"started": time.strftime("%Y-%m-%d %H:%M:%S"), "duration_s": duration, "runs": {}}
for name, args in variants:
    run = live_bench._effort_run(robot, {**args, "scenario": "default_gap", "robot": "hyq"}, duration, 60.0, 300.0)
    result["runs"][name] = {"arguments": args, **run}
    print(name, run["fell"], [(p["t_end_s"], p["effort_rms_nm"], p.get("online_learner.samples_learned"))
                              for p in run["periods"]], flush=True)
    with open(out, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1)
