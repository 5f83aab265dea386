"""The one learner contract (scikit-learn style: fit / predict / partial_fit).

Every learner of CIML — LWPR and the sparse GP — looks the same to the model set, the
CLI, the model server and the diagnosis:

- hyper-parameters are keyword arguments of ``__init__`` and stored unchanged as
  attributes of the same name (``get_params()`` returns them);
- ``fit(X, y)`` learns from scratch and returns ``self``; incremental learners also
  have ``partial_fit(X, y)`` (``supports_partial_fit = True``), which returns ``self``,
  and ``update(x, y)``, one sample without input checks (online learning);
- learned state lives in attributes whose names end in ``_`` and exists only after
  fitting (``is_fitted``);
- ``predict(X)`` returns the mean (N,), ``predict(X, return_std=True)`` returns
  ``(mean, std)``, std being the uncertainty of the learned function (not of a new
  noisy measurement); ``predict_one(x)`` the same (mean, std) at one input, without input
  checks (the 250 Hz serving path);
- away from the training data every learner falls back to a zero mean with a large
  std (the prior): a learned model error then reverts to the nominal model;
- the learned state is exported as plain arrays (``get_state``) and rebuilt from them
  (``from_state``) — the model files (ciml_learning.learning.model_files) store nothing else.

Inputs X are (N × n_features) float arrays, targets y are (N,) float arrays, both
finite. Units are whatever the caller uses; the model set standardises them.
"""
from __future__ import annotations

import inspect
import json
from abc import ABC, abstractmethod
from typing import Any, ClassVar

import numpy as np

from ciml_learning.core.errors import CimlError


class LearnerError(CimlError):
    """Bad learner input (shape, non-finite values, unknown hyper-parameter, not fitted)."""


class Learner(ABC):
    """Base class of CIML's regression learners (one output dimension each)."""

    name: ClassVar[str] = ""
    """Allow-listed learner name used in model files ("lwpr", "sgpr")."""
    supports_partial_fit: ClassVar[bool] = False
    n_features_in_: int
    """Input dimension, set by fitting (or restoring) the learner."""

    # ------------------------------------------------------------------ hyper-parameters
    @classmethod
    def _param_names(cls) -> list[str]:
        sig = inspect.signature(cls.__init__)
        return [p for p in sig.parameters if p != "self"]

    def get_params(self) -> dict[str, Any]:
        """Hyper-parameters as given to __init__ (JSON-able: numbers, strings, lists, None)."""
        return {p: _jsonable(getattr(self, p)) for p in self._param_names()}

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> "Learner":
        unknown = sorted(set(params) - set(cls._param_names()))
        if unknown:
            raise LearnerError(f"unknown {cls.name} hyper-parameter(s) {unknown}; valid: {cls._param_names()}")
        return cls(**params)

    # ------------------------------------------------------------------ contract
    @abstractmethod
    def fit(self, X: np.ndarray, y: np.ndarray) -> "Learner":
        """Learn from scratch on (X, y); returns self."""

    @abstractmethod
    def predict(self, X: np.ndarray, return_std: bool = False):
        """Mean (N,) or (mean, std) at X (N × n_features)."""

    @abstractmethod
    def predict_one(self, x: np.ndarray) -> tuple[float, float]:
        """(mean, std) at one input x (n_features,); no input checks."""

    def update(self, x: np.ndarray, y: float) -> None:
        """Learn one sample (x (n_features,), y finite; unchecked): incremental learners only."""
        raise LearnerError(f"{type(self).__name__} is batch-only (no partial_fit)")

    @abstractmethod
    def get_state(self) -> dict[str, np.ndarray]:
        """Learned state as named float/int arrays (no objects)."""

    @abstractmethod
    def _set_state(self, arrays: dict[str, np.ndarray]) -> None:
        """Restore the learned state from get_state()'s arrays (validated)."""

    @property
    def is_fitted(self) -> bool:
        return getattr(self, "n_features_in_", None) is not None

    @classmethod
    def from_state(cls, params: dict[str, Any], arrays: dict[str, np.ndarray]) -> "Learner":
        """Rebuild a fitted learner from its hyper-parameters and state arrays."""
        learner = cls.from_params(params)
        try:
            learner._set_state(arrays)
        except (KeyError, ValueError, IndexError, TypeError) as err:
            raise LearnerError(f"invalid {cls.name} state: {err}") from err
        return learner

    # ------------------------------------------------------------------ helpers
    def _check_fitted(self) -> None:
        if not self.is_fitted:
            raise LearnerError(f"{type(self).__name__} is not fitted yet; call fit() first")

    def _check_X(self, X: np.ndarray, n_features: int | None = None) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        if X.ndim == 1:
            X = X[None, :]
        if X.ndim != 2:
            raise LearnerError(f"X must be 2-D (N × n_features), got shape {X.shape}")
        if n_features is not None and X.shape[1] != n_features:
            raise LearnerError(f"X has {X.shape[1]} features, the model expects {n_features}")
        if not np.all(np.isfinite(X)):
            raise LearnerError("X contains non-finite values")
        return np.ascontiguousarray(X)

    def _check_Xy(self, X: np.ndarray, y: np.ndarray, n_features: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        X = self._check_X(X, n_features)
        y = np.asarray(y, dtype=float).reshape(-1)
        if len(y) != len(X):
            raise LearnerError(f"X has {len(X)} rows but y has {len(y)}")
        if not np.all(np.isfinite(y)):
            raise LearnerError("y contains non-finite values")
        return X, np.ascontiguousarray(y)

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in self.get_params().items())
        return f"{type(self).__name__}({args})"


def _jsonable(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (np.floating, np.integer, np.bool_)):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    json.dumps(value)  # raises for anything that is not plain data
    return value
