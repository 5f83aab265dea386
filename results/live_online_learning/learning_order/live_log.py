"""What order.py and rate_lead.py share: a trot log as the live learner gets it, and the loop that
scores a model."""
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "go1_reference_eps"))
from go1_log import learner_rows  # noqa: E402

from ciml_learning.core.profile import load_profile, profile_path  # noqa: E402
from ciml_learning.learning.snapshot_gate import ValidationConfig  # noqa: E402
from ciml_learning.logs.pipeline import load_dataset  # noqa: E402
from ciml_sim.recorder import run_headless  # noqa: E402
from ciml_sim.scenario import resolve_scenario  # noqa: E402


def load(name: str, scenario_name: str, bag: str):
    """(robot, scenario, targets, t from the log's start [s], rows the live learner learns): the
    error extractor's rows (go1_log.learner_rows) outside the held-back blocks of
    snapshot_gate.ValidationConfig. go1's bag is on CIML's topics (../go1_ciml_topics_profile.yaml)."""
    spec = os.path.join(HERE, "..", "go1_ciml_topics_profile.yaml") if name == "go1" else profile_path(name)
    profile = load_profile(spec)
    robot = profile.robot()
    tg = load_dataset(robot, [bag], progress=False, profile=profile).targets
    t = tg.t - tg.t[0]
    held = np.array([ValidationConfig().held_back(int(round(s * 1e9))) for s in t])
    return robot, resolve_scenario(scenario_name, robot), tg, t, learner_rows(tg) & ~held


def learn(ms, tg, rows: np.ndarray, part: np.ndarray) -> None:
    """partial_fit of the rows `part` (indices, in learning order), Γ where `rows` says."""
    ms.partial_fit(tg.inputs[part], tg.generalized_error[part], tg.generalized_observed[part],
                   tg.actuation_error[part], tg.valid[part], tg.leg_coupling[part], effort_valid=rows[part])


def effort(robot, scenario, epsilon_fn) -> float:
    """RMS feedback effort [Nm] of trot_35, 30 s, seed 11, with ε from epsilon_fn (None: nominal)."""
    return round(run_headless(robot, scenario, "trot_35", 30.0, 11, epsilon_fn=epsilon_fn,
                              progress=False).metrics()["rms_feedback_effort_nm"], 3)
