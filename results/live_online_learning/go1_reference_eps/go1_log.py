"""What drift.py and clip_inputs.py share: a go1_gap log as the learner sees it, in its learning order."""
import os

import numpy as np

from ciml_learning.core.profile import load_profile
from ciml_learning.learning.model_epsilon import EpsilonFunction
from ciml_learning.logs.pipeline import load_dataset
from ciml_learning.ros.node_params import ERROR_EXTRACTOR
from ciml_sim.recorder import run_headless
from ciml_sim.scenario import resolve_scenario

HERE = os.path.dirname(os.path.abspath(__file__))
profile = load_profile(os.path.join(HERE, "..", "go1_ciml_topics_profile.yaml"))
robot = profile.robot()
scenario = resolve_scenario("go1_gap", robot)


def learner_rows(tg) -> np.ndarray:
    """The rows the live learner gets: the valid ones and every effort_sample_every-th (the error
    extractor's default) of those usable for Γ only, near a contact change."""
    every = ERROR_EXTRACTOR.get("effort_sample_every").default
    return tg.valid | (tg.effort_valid & (np.cumsum(tg.effort_valid & ~tg.valid) % every == 0))


def load(bag: str):
    """(targets, learner_rows) of a go1_gap bag on CIML's topics."""
    tg = load_dataset(robot, [bag], progress=False, profile=profile).targets
    return tg, learner_rows(tg)


def learning_order(rows: np.ndarray, buffer: int, rng=None) -> np.ndarray:
    """rows in the order a streaming shuffle of `buffer` samples learns them (each new one takes a
    random slot, the one it displaces is learned; the buffer's last content stays unlearned, as it
    would live); buffer ≤ 0: as they come."""
    if buffer <= 0:
        return rows
    rng = np.random.default_rng(0) if rng is None else rng
    slots, out = [], []
    for r in rows:
        if len(slots) < buffer:
            slots.append(r)
            continue
        k = int(rng.integers(buffer))
        out.append(slots[k])
        slots[k] = r
    return np.array(out, dtype=np.int64)


def effort(fn) -> float:
    """RMS feedback effort [Nm] of trot_35, 30 s, seed 11, with ε from fn (a model set, an ε
    function or None: nominal)."""
    if fn is not None and not callable(fn):
        fn = EpsilonFunction(robot, fn)
    return round(run_headless(robot, scenario, "trot_35", 30.0, 11, epsilon_fn=fn,
                              progress=False).metrics()["rms_feedback_effort_nm"], 3)
