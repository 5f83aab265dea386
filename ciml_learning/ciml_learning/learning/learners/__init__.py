"""Learners of the model error, all with one contract (see base.py).

LEARNERS is the allow-list of learner names that model files may name; a model file
is rebuilt only through it (never by evaluating names read from a file).
"""
from __future__ import annotations

from ciml_learning.learning.learners.base import Learner, LearnerError
from ciml_learning.learning.learners.lwpr import LWPR, LWPRStack
from ciml_learning.learning.learners.sgpr import SparseGPR

LEARNERS: dict[str, type[Learner]] = {"lwpr": LWPR, "sgpr": SparseGPR}


def learner_class(name: str) -> type[Learner]:
    """The learner class of an allow-listed name; LearnerError naming the valid ones otherwise."""
    try:
        return LEARNERS[name]
    except (KeyError, TypeError):
        raise LearnerError(f"unknown learner {name!r}; valid: {sorted(LEARNERS)}") from None


__all__ = ["LEARNERS", "LWPR", "LWPRStack", "Learner", "LearnerError", "SparseGPR", "learner_class"]
