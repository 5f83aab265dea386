"""The live learner's sample order against a streaming shuffle, headless.

    python order.py ROBOT SCENARIO BAG BUFFER SEED MINUTES,...

ROBOT: go1 (the bag on CIML's topics: ../go1_ciml_topics_profile.yaml) or hyq. BAG: a 600 s
trot_35 recorded under the nominal controller (`ciml record [--robot …] --scenario SCENARIO
--motion trot_35 --duration 600 --seed 21 --no-ground-truth`). The bag's samples are learned as
the live learner gets them: the error extractor's rows (go1_log.learner_rows), one 0.5 s block of
stamps in 5 held back (snapshot_gate.ValidationConfig, not learned), then either in time order
(BUFFER 0: what online.OnlineLearner does today) or through a streaming shuffle of BUFFER samples
(go1_log.learning_order with rng SEED). After each of MINUTES of the log, the model so far
drives a closed loop (trot_35 30 s, seed 11; RMS feedback effort [Nm]).
"""
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "go1_reference_eps"))
from go1_log import learning_order  # noqa: E402
from live_log import effort, learn, load  # noqa: E402

from ciml_learning.learning.model_epsilon import EpsilonFunction  # noqa: E402
from ciml_learning.learning.models import ModelSet  # noqa: E402

name, scenario_name, bag, buffer, seed = sys.argv[1:6]
minutes = [float(m) for m in sys.argv[6].split(",")]
robot, scenario, tg, t, rows = load(name, scenario_name, bag)
order = learning_order(np.flatnonzero(rows), int(buffer), np.random.default_rng(int(seed)))
ms = ModelSet.for_robot(robot, "lwpr")
start, out = 0, []
for minute in minutes:
    end = int(np.sum(t[order] < 60.0 * minute)) if int(buffer) > 0 else int(np.searchsorted(t[order], 60.0 * minute))
    learn(ms, tg, rows, order[start:end])
    start = end
    out.append(effort(robot, scenario, EpsilonFunction(robot, ms)))
print(f"{name} buffer {buffer} seed {seed}: effort after {','.join(f'{m:g}' for m in minutes)} min: {out}",
      flush=True)
