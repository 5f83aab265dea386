"""The rollback watch of a served model (ciml_learning.learning.rollback): pure, no ROS."""
from __future__ import annotations

import numpy as np
import pytest

from ciml_learning.learning.rollback import (
    NOMINAL_SOURCE,
    SUDDEN_RISE,
    WORSE_THAN_BEFORE,
    EffortWatch,
    RollbackConfig,
    feedback_effort,
)

DT = 0.004  # 250 Hz


def run(watch: EffortWatch, t0: float, seconds: float, source: str, effort: float, error: float = 0.01,
        seed: int = 0):
    """Feed `seconds` of steps with noisy effort [Nm] and base error [m]; the rollbacks returned."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(int(round(seconds / DT))):
        e = effort * (1.0 + 0.1 * np.sin(2 * np.pi * 1.7 * k * DT)) + rng.normal(scale=2.0)
        back = watch.update(t0 + k * DT, source, (abs(e), error))
        if back is not None:
            out.append((t0 + k * DT, back))
    return out, t0 + seconds


def test_a_model_that_raises_the_effort_is_rolled_back_within_the_window_and_a_good_one_becomes_safe():
    w = EffortWatch(RollbackConfig(window=0.25, baseline=5.0, probation=10.0, rise=1.5, margins=(15.0, 0.03)))
    backs, t = run(w, 0.0, 6.0, NOMINAL_SOURCE, 45.0)
    assert backs == []
    backs, t = run(w, t, 12.0, "lwpr:snapshot-000001", 30.0, seed=1)   # better than nominal
    assert backs == [] and w.safe == "lwpr:snapshot-000001"
    t_bad = t
    backs, t = run(w, t, 2.0, "lwpr:snapshot-000002", 120.0, seed=2)  # 4× the effort
    assert len(backs) == 1                                            # once per model
    at, back = backs[0]
    assert back.source == "lwpr:snapshot-000002" and back.signal == "feedback_effort"
    assert back.limit == pytest.approx(1.5 * 30.0 + 15.0, rel=0.1)    # the RMS of the 5 s before it
    assert at - t_bad == pytest.approx(back.detected_after) and back.detected_after <= 0.25 + DT
    assert back.kind == SUDDEN_RISE
    assert "lwpr:snapshot-000002" in w.rolled_back and w.safe == "lwpr:snapshot-000001"
    # the last safe model back: served again without a new probation against the bad seconds
    backs, t = run(w, t, 3.0, "lwpr:snapshot-000001", 60.0, seed=3)
    assert backs == []


def test_the_base_tracking_error_rolls_back_too_and_a_modest_rise_does_not():
    w = EffortWatch()
    _, t = run(w, 0.0, 6.0, NOMINAL_SOURCE, 45.0, error=0.01)
    backs, t = run(w, t, 10.5, "m1", 46.5, error=0.02, seed=1)        # +3 %, +1 cm: within noise and margins
    assert backs == [] and w.safe == "m1"
    backs, _ = run(w, t, 1.0, "m2", 50.0, error=0.12, seed=2)         # sagging 12 cm
    assert [b.signal for _, b in backs] == ["base_position_error"]


def test_a_model_worse_than_the_one_before_it_is_rolled_back_once_assessed():
    """A snapshot that makes the loop 15 % worse — no sudden rise — goes `assess` seconds after it
    served; one 3 % worse (within a trot's spread) and a better one stay; one replaced before its
    assessment is not judged."""
    w = EffortWatch()                                                  # assess 5 s, worse 8 %
    _, t = run(w, 0.0, 6.0, NOMINAL_SOURCE, 50.0)
    backs, t = run(w, t, 6.0, "m1", 35.0, seed=1)                      # better: stays
    assert backs == []
    t_swap = t
    backs, t = run(w, t, 6.0, "m2", 40.25, seed=2)                     # +15 % over m1's 35 Nm
    assert [(b.source, b.kind, b.signal) for _, b in backs] == [("m2", WORSE_THAN_BEFORE, "feedback_effort")]
    at, back = backs[0]
    assert at - t_swap == pytest.approx(5.0, abs=2 * DT) and back.limit == pytest.approx(1.08 * 35.0, rel=0.03)
    assert "m2" in w.rolled_back
    backs, t = run(w, t, 1.0, "m1", 35.0, seed=3)                      # the server serves m1 again …
    backs, t = run(w, t, 6.0, "m2b", 40.25, seed=7)                    # … and as bad a model comes 1 s later:
    assert [b.source for _, b in backs] == ["m2b"]                     # judged against m1, not against m2
    backs, t = run(w, t, 6.0, "m1", 35.0, seed=3)
    backs, t = run(w, t, 6.0, "m3", 36.0, seed=4)                      # +3 %: stays
    assert backs == []
    backs, t = run(w, t, 3.0, "m4", 45.0, seed=5)                      # replaced after 3 s: not judged
    backs2, t = run(w, t, 6.0, "m5", 36.0, seed=6)
    assert backs == [] and backs2 == []
    with pytest.raises(ValueError):
        RollbackConfig(assess=20.0)                                    # after the probation


def test_a_kept_model_put_back_by_a_rollback_is_not_judged_again():
    """m2 passed its assessment; m3 is rolled back and m2 serves again, now in a stretch where it
    costs more than m3's reference allowed: it stays (judging it again rolled back the models before
    it one after another, down to the nominal model)."""
    w = EffortWatch()                                                  # worse 8 %
    _, t = run(w, 0.0, 6.0, NOMINAL_SOURCE, 50.0)
    backs, t = run(w, t, 6.0, "m1", 35.0, seed=1)
    backs2, t = run(w, t, 6.0, "m2", 36.0, seed=2)
    assert backs == backs2 == [] and {"m1", "m2"} <= w.kept
    backs, t = run(w, t, 6.0, "m3", 45.0, seed=3)                      # +25 %: goes at 5 s
    assert [(b.source, b.kind) for _, b in backs] == [("m3", WORSE_THAN_BEFORE)]
    backs, t = run(w, t, 12.0, "m2", 42.0, seed=4)                     # m2 back, costing more now: kept
    assert backs == []
    backs, t = run(w, t, 6.0, "m4", 41.0, seed=5)                      # judged against m2's 42 Nm: stays
    assert backs == []


def test_without_a_baseline_nothing_is_judged_and_bad_values_are_ignored():
    w = EffortWatch()
    backs, t = run(w, 0.0, 1.0, "m1", 300.0)                          # served from the start: no reference
    assert backs == []
    assert w.update(t, "m1", (float("nan"), 0.0)) is None
    with pytest.raises(ValueError):
        RollbackConfig(window=0.0)


def test_every_new_model_is_counted_judged_or_unjudged():
    w = EffortWatch()
    assert run(w, 0.0, 3.0, "m1", 40.0)[0] == []                # no 5 s before it: no reference
    assert (w.judged, w.unjudged) == (0, 1)
    _, t = run(w, 3.0, 6.0, NOMINAL_SOURCE, 45.0)
    _, t = run(w, t, 6.0, "m2", 44.0, seed=1)                   # assessed at 5 s, passes
    _, t = run(w, t, 3.0, "m3", 44.0, seed=2)                   # replaced at 3 s, before its assessment
    backs, t = run(w, t, 6.0, "m4", 60.0, seed=3)               # assessed at 5 s: worse, rolled back
    assert [b.kind for _, b in backs] == [WORSE_THAN_BEFORE]
    backs, t = run(w, t, 1.0, "m5", 150.0, seed=4)              # a sudden rise
    assert [b.kind for _, b in backs] == [SUDDEN_RISE]
    assert (w.judged, w.unjudged) == (3, 2)
    _, t = run(w, t, 6.0, "m2", 44.0, seed=5)                   # a kept model put back: not judged again
    assert (w.judged, w.unjudged) == (3, 2)


def test_feedback_effort_is_the_joint_loops_pd_plus_linearization():
    kp, kd = np.full(3, 300.0), np.full(3, 8.0)
    q, qd = np.array([0.1, 0.2, 0.3]), np.array([1.0, 0.0, -1.0])
    q_t, qd_t, lin = np.array([0.2, 0.2, 0.2]), np.zeros(3), np.array([1.0, 2.0, 3.0])
    expected = np.linalg.norm(kp * (q_t - q) + kd * (qd_t - qd) + lin)
    assert feedback_effort(kp, kd, q_t, qd_t, lin, q, qd) == pytest.approx(expected)


def test_the_effort_margin_scales_with_the_robot():
    """A tenth of the largest joint torque limit: HyQ's 15 Nm, go1's 3.6 Nm (a fixed 15 Nm against
    go1's ~3 Nm trot would never see a sudden rise in effort)."""
    from ciml_learning.core.profile import load_profile
    from ciml_learning.learning.rollback import margins_for

    hyq, go1 = (margins_for(load_profile(n).robot().torque_limits) for n in ("hyq", "go1"))
    assert hyq == (15.0, 0.03) and go1 == (pytest.approx(3.555), 0.03)
    for margins, rolled_back in ((go1, True), (hyq, False)):
        w = EffortWatch(RollbackConfig(margins=margins))
        backs = []
        for k in range(int(7.0 / DT)):   # go1's trot (3.2 Nm) 5 s, then a model that takes it to 9 Nm
            t = k * DT
            effort = 3.2 * (1.0 + 0.1 * np.sin(2 * np.pi * 1.7 * t)) if t < 5.0 else 9.0
            back = w.update(t, NOMINAL_SOURCE if t < 5.0 else "m1", (effort, 0.01))
            if back is not None:
                backs.append(back)
        assert [b.kind for b in backs] == ([SUDDEN_RISE] if rolled_back else []), margins
        assert not rolled_back or backs[0].detected_after <= 0.3
