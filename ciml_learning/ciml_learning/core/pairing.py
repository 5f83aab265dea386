"""The sample-pairing rule: which base, contact, IMU and command sample goes with a joint sample.

A robot log is sampled at its joint-state stamps. For a joint sample stamped t, each other
role's sample is the latest one stamped at or before t — the command strictly before t (a
command stamped t was computed from the sample at t and acts after it; TorqueCommand.msg) —
and is used only if it is at most `age_limit_ns` older than t: the larger of max_age_s and
AGE_PERIODS periods of that role's topic (a topic slower than the joint states is still
paired with every joint sample between two of its messages).

The one home of this rule: loginputs.load_log applies it to a whole log (partner_indices),
the state_filter node to one joint sample at a time (add_to_history, partner). A filtered state
and the /reference of its instant pair by the nearest stamp instead (nearest, ReferenceHistory:
the online learner's tracking check in error_extractor), as do id_controller's step and the
reference and prediction of its instant. Pure module: numpy only.
"""
from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Sequence
from typing import Any

import numpy as np

from ciml_learning.core.stamps import measure_rate

AGE_PERIODS = 2.5
"""A partner may be this many of its topic's periods old (when that is more than max_age_s)."""

STRICT_ROLES = frozenset({"command"})
"""Roles paired strictly before the joint sample's stamp; the others at or before it."""


def is_strict(role: str) -> bool:
    """Whether `role` pairs strictly before the joint sample (the command) or at or before it."""
    return role in STRICT_ROLES


def age_limit_ns(max_age_s: float, partner_stamps_ns: np.ndarray | Sequence[int]) -> int:
    """The oldest a partner may be [ns]: max(max_age_s, AGE_PERIODS / its topic's rate), the
    rate measured from the partner's stamps (stamps.measure_rate; none with fewer than two)."""
    rate = measure_rate(np.asarray(partner_stamps_ns, dtype=float) * 1e-9).rate_hz
    return int(max(max_age_s, AGE_PERIODS / rate if np.isfinite(rate) else 0.0) * 1e9)


def partner_indices(partner_t: np.ndarray, t: np.ndarray, max_age_ns: int, strict: bool = False) -> np.ndarray:
    """For each joint stamp in t, the index of the latest partner stamp (sorted partner_t) at or
    before it (strictly before with `strict`); −1 if there is none or it is older than max_age_ns."""
    idx = np.searchsorted(partner_t, t, side="left" if strict else "right") - 1
    ok = idx >= 0
    ok[ok] &= (t[ok] - partner_t[idx[ok]]) <= max_age_ns
    idx[~ok] = -1
    return idx


def _stamp(entry: tuple[int, object]) -> int:
    return entry[0]


def add_to_history(history: deque[tuple[int, object]], stamp: int, value: object) -> None:
    """Append (stamp, value) to a role's history, which partner() needs in stamp order: a message
    that arrives after a later-stamped one is inserted where its stamp belongs (after any of the
    same stamp, as a stable sort of the log would place it). A full history drops its oldest."""
    if not history or stamp >= history[-1][0]:
        history.append((stamp, value))
        return
    i = bisect.bisect_right(history, stamp, key=_stamp)
    if history.maxlen is not None and len(history) == history.maxlen:
        if i == 0:  # older than everything kept
            return
        history.popleft()
        i -= 1
    history.insert(i, (stamp, value))


def partner(history: deque[tuple[int, object]], stamp: int, max_age_s: float, strict: bool = False):
    """The (stamp, value) of `history` (a role's recent samples in stamp order: add_to_history) that
    pairs with the joint sample stamped `stamp` [ns], or None: partner_indices for one sample, by
    bisection (the state_filter calls this for every joint sample and role), the age limit measured
    from the history's stamps only when the partner is older than max_age_s."""
    i = (bisect.bisect_left if strict else bisect.bisect_right)(history, stamp, key=_stamp) - 1
    if i < 0:
        return None
    age = stamp - history[i][0]
    if age <= int(max_age_s * 1e9):
        return history[i]
    stamps = np.fromiter((s for s, _ in history), dtype=np.int64, count=len(history))
    return history[i] if age <= age_limit_ns(max_age_s, stamps) else None


def nearest(history: deque[tuple[int, object]], stamp: int, max_age_ns: int):
    """The (stamp, value) of `history` (stamp order: add_to_history) nearest to `stamp` [ns] within
    max_age_ns either way, or None."""
    i = bisect.bisect_left(history, stamp, key=_stamp)
    best = min((j for j in (i - 1, i) if 0 <= j < len(history)), key=lambda j: abs(history[j][0] - stamp),
               default=None)
    return history[best] if best is not None and abs(history[best][0] - stamp) <= max_age_ns else None


class ReferenceHistory:
    """The recent samples (stamp [ns], value) of one stream stamped by the instant they are for
    (/reference, /model_error/predicted), in stamp order, and the one of an instant: the nearest
    stamp within `max_age_ns` (nearest). A stamp not after the newest is a restarted stream (or out
    of order): the history starts over, never mixing two streams. error_extractor attaches the
    reference of each learning sample's instant; id_controller takes each step's reference and
    that reference's prediction."""

    def __init__(self, max_age_ns: int, max_references: int = 500) -> None:
        self.max_age_ns = int(max_age_ns)
        self._references: deque[tuple[int, Any]] = deque(maxlen=max_references)
        self.heard = 0

    def add(self, stamp_ns: int, value: Any) -> None:
        stamp_ns = int(stamp_ns)
        if self._references and stamp_ns <= self._references[-1][0]:
            self._references.clear()
        self._references.append((stamp_ns, value))
        self.heard += 1

    @property
    def newest(self) -> int | None:
        """Stamp [ns] of the newest reference kept (None before the first)."""
        return self._references[-1][0] if self._references else None

    def at(self, stamp_ns: int) -> Any | None:
        """The value of the reference nearest `stamp_ns` within max_age_ns, else None."""
        found = nearest(self._references, int(stamp_ns), self.max_age_ns)
        return None if found is None else found[1]
