"""The sample-pairing rule (ciml_learning.core.pairing), used by the offline log reader and the
state_filter node: the same partner for every joint sample, one sample at a time or a whole log."""
from __future__ import annotations

from collections import deque

import numpy as np

from ciml_learning.core.pairing import AGE_PERIODS, add_to_history, age_limit_ns, is_strict, partner, partner_indices

MS = 1_000_000


def test_latest_at_or_before_and_strictly_before():
    src = np.array([0, 4, 8, 12]) * MS
    t = np.array([-1, 0, 3, 4, 5, 12, 40]) * MS
    assert partner_indices(src, t, 10 * MS).tolist() == [-1, 0, 0, 1, 1, 3, -1]
    assert partner_indices(src, t, 10 * MS, strict=True).tolist() == [-1, -1, 0, 0, 1, 2, -1]
    assert is_strict("command") and not any(is_strict(r) for r in ("base", "contacts", "imu"))


def test_age_limit_is_max_age_or_periods_of_the_topic():
    assert age_limit_ns(0.02, np.arange(50) * 4 * MS) == 20 * MS           # 250 Hz: 2.5 periods = 10 ms
    assert age_limit_ns(0.02, np.arange(50) * 25 * MS) == int(AGE_PERIODS * 25 * MS)  # 40 Hz: 62.5 ms
    assert age_limit_ns(0.02, [7 * MS]) == 20 * MS                         # one stamp: no rate


def test_one_sample_at_a_time_equals_the_whole_log():
    """partner(history, …) at each joint sample (online) == partner_indices over the log (offline),
    with the partner's recent history only, for fast, slow and strict partners."""
    rng = np.random.default_rng(5)
    tj = np.cumsum(rng.integers(900_000, 1_100_000, 600))  # ~1 kHz joint samples
    for period, strict in ((4 * MS, True), (4 * MS, False), (30 * MS, False), (1 * MS, False)):
        n = int(tj[-1] // period) + 2  # over the whole log
        src = np.cumsum(rng.integers(int(0.9 * period), int(1.1 * period), n)) + int(rng.integers(0, period))
        src = src[rng.random(len(src)) > 0.05]  # a few lost messages
        offline = partner_indices(src, tj, age_limit_ns(0.02, src), strict)
        history: deque = deque(maxlen=16)
        k = 0
        for i, stamp in enumerate(tj):
            while k < len(src) and src[k] <= stamp + 2 * period:  # messages that have arrived
                add_to_history(history, int(src[k]), k)
                k += 1
            got = partner(history, int(stamp), 0.02, strict)
            expect = offline[i]
            assert (got[1] if got is not None else -1) == expect or history[0][1] > expect >= 0, (period, i)
        assert (offline >= 0).mean() > 0.9


def test_history_out_of_arrival_order_is_paired_by_stamp():
    history: deque = deque(maxlen=4)
    for stamp, value in ((0, "a"), (8 * MS, "c"), (4 * MS, "b")):
        add_to_history(history, stamp, value)
    assert [v for _, v in history] == ["a", "b", "c"]
    assert partner(history, 5 * MS, 0.02) == (4 * MS, "b")
    assert partner(history, 8 * MS, 0.02, strict=True) == (4 * MS, "b")
    assert partner(deque(), 5 * MS, 0.02) is None
    assert partner(history, 100 * MS, 0.02) is None  # older than max(20 ms, 2.5 periods)
    add_to_history(history, 8 * MS, "c2")          # the same stamp again: after the first, as a stable sort
    add_to_history(history, 6 * MS, "d")           # full (4): the oldest goes, the late one is inserted
    assert [v for _, v in history] == ["b", "d", "c", "c2"]
    assert partner(history, 9 * MS, 0.02) == (8 * MS, "c2")
    add_to_history(history, 1 * MS, "e")           # older than everything kept: dropped
    assert [v for _, v in history] == ["b", "d", "c", "c2"]
