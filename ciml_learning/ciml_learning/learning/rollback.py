"""Rolling back a served model that makes the robot worse (docs/LIVE_GRAPH.md, "Safety").

The snapshot gate (snapshot_gate) checks a model on held-back data before it is served; this
module watches it while it is served. The controller feeds every step's feedback effort
‖u_fb‖ (feedback_effort, the paper's Tables I–II) and base position error ‖p − pᵈ‖ to an
EffortWatch together with the `source` of the model error it used. When a new model starts to
serve, the RMS of each signal over the `baseline` seconds before it is frozen; for the next
`probation` seconds the RMS over the last `window` seconds of the new model is compared with it,
and a rise beyond rise × baseline + margin on either signal names the model to roll back (a
sudden rise: safety). Then, `assess` seconds after it served, the RMS effort of all its steps so
far is compared with the baseline's, and a model more than `worse` above it goes too (worse
than the model before it: online learning must keep helping, and a snapshot that predicts
held-back data better than nominal can still cost effort in the loop — results/LIVE_GRAPH.md,
thirteenth, sixteenth and seventeenth sessions). The reference is the seconds just before the
model, not a best level kept from earlier: under one fixed model the 5 s RMS effort moved from
15.7 to ~30 Nm within a minute and from 30.7 to ~50 Nm within two (seventeenth session; the trot
leaning one way or the other at the old base gain, eighteenth), so an
earlier level is no measure of what the model serving now achieves (judged against such a best
level, candidates better than the model serving were refused for minutes). A model that passed
its assessment (or served its probation) is not judged again when a rollback puts it back: it
was judged in its own time, and judging it again against the rolled-back one's reference rolled
back the models before it one after another, down to the nominal model (seventeenth session). A
model that has served its probation becomes the last safe one.

Why these defaults: a model that is wrong where the robot is raises the effort from its first
command on, and detection takes one `window` after it serves (measured live: 252 ms,
test_live_safety); the one learned fall seen live took ~1 s from the served model to the ground
(docs/LIVE_GRAPH.md). The margins and the factor 1.5 leave room for a healthy trot's spread of
the 0.25 s RMS between windows (results/LIVE_GRAPH.md): the effort margin is a tenth of the robot's
largest joint torque limit (margins_for: 15 Nm on HyQ, 3.6 Nm on go1; measured live, trot_35 under
the nominal model, 60 s: a window's RMS at most 1.43 × (HyQ, 41 Nm) and 1.23 × (go1, 3.2 Nm) the 5 s
before it, so 1.5 × alone was never exceeded; a fixed 15 Nm had left go1, whose effort is ~3 Nm,
without the effort check), the position margin 3 cm. `worse` 8 %: under one
model the RMS effort of the 10 s after an instant is within 1.024 × (p95; 1.04 at most) of the 5 s
before it (trot_35, 97 instants; results/LIVE_GRAPH.md, sixteenth session), and a served snapshot
that made a run worse raised the effort by 14–24 % from one minute to the next; `assess` 5 s: the model
server serves each model at least `min_serve_time` (6 s, serving.SwapHold), so every model is
assessed; a model replaced before its assessment (another server setting) is not judged.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

NOMINAL_SOURCE = "nominal"
SIGNALS = ("feedback_effort", "base_position_error")
"""What EffortWatch watches: [Nm] and [m]."""


def feedback_effort(stiffness: np.ndarray, damping: np.ndarray, position_target: np.ndarray,
                    velocity_target: np.ndarray, feedback_linearization: np.ndarray, q: np.ndarray,
                    qd: np.ndarray) -> float:
    """‖u_fb,pd + u_fb,lin‖ [Nm] of one command on the joint sample (q, q̇) it was computed for:
    u_fb,pd = K_p (qᵈ − q) + K_d (q̇ᵈ − q̇) as the joint loop computes it (TorqueCommand.msg)."""
    pd = stiffness * (position_target - q) + damping * (velocity_target - qd) + feedback_linearization
    return float(np.sqrt(pd @ pd))


EFFORT_MARGIN_SHARE = 0.1
"""The sudden-rise margin on the feedback effort, as a share of the robot's largest joint torque limit."""
POSITION_MARGIN = 0.03
"""[m] The sudden-rise margin on the base position error."""


def margins_for(torque_limits: np.ndarray) -> tuple[float, float]:
    """RollbackConfig.margins of a robot with these joint torque limits [Nm]: (effort [Nm], position [m])."""
    return EFFORT_MARGIN_SHARE * float(np.max(torque_limits)), POSITION_MARGIN


@dataclass(frozen=True)
class RollbackConfig:
    window: float = 0.25                      # [s] RMS window of the served model
    baseline: float = 5.0                     # [s] before the model served, its reference
    probation: float = 10.0                   # [s] a new model is watched this long
    rise: float = 1.5                         # × the baseline RMS …
    margins: tuple[float, float] = (15.0, POSITION_MARGIN)  # … + these per signal [Nm, m] (HyQ's: margins_for)
    assess: float = 5.0                       # [s] after serving, the model's whole RMS effort …
    worse: float = 0.08                       # … may exceed the baseline's by this share at most

    def __post_init__(self) -> None:
        if not (self.window > 0 and self.baseline >= self.window and self.probation >= self.window
                and self.rise >= 1.0 and len(self.margins) == len(SIGNALS) and min(self.margins) >= 0
                and self.window <= self.assess <= self.probation and self.worse >= 0):
            raise ValueError(f"invalid rollback settings {self}")


SUDDEN_RISE, WORSE_THAN_BEFORE = "sudden_rise", "worse_than_before"
"""The two reasons of a Rollback (its `kind`)."""


@dataclass
class Rollback:
    source: str
    signal: str
    rms: float
    limit: float
    detected_after: float   # [s] since the model first served
    kind: str = SUDDEN_RISE


class _Window:
    """Running mean of squares of the steps in the last `length` seconds (O(1) per step)."""

    def __init__(self, length: float) -> None:
        self.length = length
        self.items: deque[tuple[float, np.ndarray]] = deque()
        self.total = np.zeros(len(SIGNALS))

    def add(self, t: float, squares: np.ndarray) -> None:
        self.items.append((t, squares))
        self.total = self.total + squares
        while self.items[0][0] <= t - self.length:
            self.total = self.total - self.items.popleft()[1]

    def clear(self) -> None:
        self.items.clear()
        self.total = np.zeros(len(SIGNALS))

    def drop_since(self, t0: float) -> None:
        """Forget the steps at or after t0 (the newest first)."""
        while self.items and self.items[-1][0] >= t0:
            self.total = self.total - self.items.pop()[1]

    def covered(self) -> float:
        return self.items[-1][0] - self.items[0][0] if self.items else 0.0

    def rms(self) -> np.ndarray:
        return np.sqrt(np.maximum(self.total, 0.0) / max(len(self.items), 1))


class EffortWatch:
    """update(t, source, signals) per control step → a Rollback when the model serving now must
    go (once per model), else None. `safe` is the last model that served its probation.
    `judged` counts the new models assessed or rolled back, `unjudged` those that were not (no
    reference before them, or replaced before their assessment); a kept model put back is neither."""

    def __init__(self, config: RollbackConfig | None = None) -> None:
        self.config = config or RollbackConfig()
        self._before = _Window(self.config.baseline)   # every step: the reference of the next model
        self._served = _Window(self.config.window)     # the current model's steps
        self.current: str | None = None      # the newest non-nominal source seen
        self.safe: str = NOMINAL_SOURCE
        self.rolled_back: set[str] = set()
        self._since = 0.0
        self._baseline: np.ndarray | None = None  # RMS per signal before the current model; None: not watched
        self._limit: np.ndarray | None = None     # sudden-rise limit per signal
        self._sum = 0.0                           # squared efforts of the current model's steps until assessed
        self._steps = 0
        self._after_rollback: np.ndarray | None = None  # the reference of the model restored by a rollback
        self.kept: set[str] = set()  # models that passed their assessment or served their probation
        self.judged = 0
        self.unjudged = 0
        self._pending = False  # the current model awaits its judgement

    def update(self, t: float, source: str, signals) -> Rollback | None:
        c = self.config
        values = np.asarray(signals, dtype=float)
        if not np.all(np.isfinite(values)):
            return None
        if source != NOMINAL_SOURCE and source not in self.rolled_back and source != self.current:
            # a new model serves from now: the reference is the RMS of the steps before it
            self._promote(t)
            self.current, self._since = source, t
            enough = self._before.covered() >= 0.5 * c.baseline
            # a model put back by a rollback was judged in its own time (kept: assessed or served its probation)
            reference = self._before.rms() if enough else self._after_rollback
            self._baseline = reference if source not in self.kept else None
            self.unjudged += self._pending  # the model it replaces was never judged
            self._pending = self._baseline is not None
            self.unjudged += self._baseline is None and source not in self.kept
            self._limit = c.rise * self._baseline + np.asarray(c.margins) if self._baseline is not None else None
            self._served.clear()
            self._sum, self._steps = 0.0, 0
        squares = values * values
        if source not in self.rolled_back:  # a rolled-back model's last steps are no reference either
            self._before.add(t, squares)
        if source != self.current or source in self.rolled_back or self._limit is None:
            return None
        age = t - self._since
        if age > c.probation:
            self._promote(t)
            return None
        self._served.add(t, squares)
        if self._steps >= 0:  # not assessed yet
            self._sum += float(squares[0])
            self._steps += 1
            back = self._assess(source, age) if age >= c.assess else None
            if back is not None:
                return back
        if age < c.window:
            return None
        rms = self._served.rms()
        over = np.flatnonzero(rms > self._limit)
        if not len(over):
            return None
        i = int(over[0])
        return self._roll_back(Rollback(source, SIGNALS[i], float(rms[i]), float(self._limit[i]), age))

    def _assess(self, source: str, age: float) -> Rollback | None:
        """`assess` seconds in: the model's RMS effort so far against (1 + worse) × the baseline's."""
        assert self._baseline is not None
        rms = math.sqrt(self._sum / self._steps)
        limit = (1.0 + self.config.worse) * float(self._baseline[0])
        self._steps = -1
        if rms <= limit:
            self.judged += 1
            self._pending = False
            self._after_rollback = None  # a model has served long enough since: its steps are the reference
            self.kept.add(source)
            return None
        return self._roll_back(Rollback(source, SIGNALS[0], rms, limit, age, WORSE_THAN_BEFORE))

    def _roll_back(self, back: Rollback) -> Rollback:
        """The model goes; its steps are no reference for the next model (else a model as bad as it
        would pass against it)."""
        self.judged += self._pending
        self._pending = False
        self.rolled_back.add(back.source)
        self._before.drop_since(self._since)
        # the model before it serves again; until its own steps cover the baseline, the reference of
        # the next model is the one the rolled-back model was judged against
        self._after_rollback = self._baseline
        return back

    def _promote(self, t: float) -> None:
        """The current model becomes the last safe one once it has served its probation unharmed."""
        if (self.current is not None and self.current not in self.rolled_back and self._limit is not None
                and t - self._since >= self.config.probation):
            self.safe = self.current
            self.kept.add(self.current)

    @staticmethod
    def base_position_error(q: np.ndarray, q_ref: np.ndarray) -> float:
        """‖p − pᵈ‖ [m] of Pinocchio configurations."""
        return math.dist(q[:3], q_ref[:3])
