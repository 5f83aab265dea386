"""BagWriter: MCAP chunk compression option and pre-serialised messages."""
from __future__ import annotations

import numpy as np
import pytest

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.robot import load_robot
from ciml_learning.logs import bagio
from ciml_learning.logs.bagio import BagError, BagWriter

ROBOT = load_robot()


def _joint_states(n: int):
    rng = np.random.default_rng(0)
    nj = ROBOT.n_joints
    return [(4_000_000 * k, cv.joint_state_msg(ROBOT, 4_000_000 * k, rng.normal(size=nj), rng.normal(size=nj),
                                               rng.normal(size=nj))) for k in range(n)]


def _mcap_bytes(path) -> bytes:
    (mcap,) = list(path.glob("*.mcap"))
    return mcap.read_bytes()


def test_zstd_compression_round_trips_and_shrinks_the_bag(tmp_path):
    msgs = _joint_states(3000)
    for name, compression in (("plain", None), ("zstd", "zstd")):
        with BagWriter(tmp_path / name, compression=compression) as w:
            for ns, m in msgs:
                w.write(topics.JOINT_STATES, ns, m)
    plain, packed = _mcap_bytes(tmp_path / "plain"), _mcap_bytes(tmp_path / "zstd")
    assert len(packed) < 0.6 * len(plain)  # the 12 joint names repeat in every message
    # standard MCAP chunk compression: the chunk records name their compression
    assert b"zstd" in packed and b"zstd" not in plain
    a = bagio.read_messages(tmp_path / "plain", [topics.JOINT_STATES])[topics.JOINT_STATES]
    b = bagio.read_messages(tmp_path / "zstd", [topics.JOINT_STATES])[topics.JOINT_STATES]
    assert len(a) == len(b) == len(msgs)
    for (sa, ma), (sb, mb), (s0, m0) in zip(a, b, msgs):
        assert sa == sb == s0
        assert list(ma.position) == list(mb.position) == list(m0.position)
        assert list(mb.name) == list(ROBOT.joint_names)


def test_unknown_compression_is_a_one_line_error(tmp_path):
    with pytest.raises(BagError, match="valid: none, zstd"):
        BagWriter(tmp_path / "bag", compression="lz4")
    assert not (tmp_path / "bag").exists()


def test_write_serialized_stores_the_bytes_as_given(tmp_path):
    from rclpy.serialization import serialize_message

    data = [(ns, serialize_message(m)) for ns, m in _joint_states(5)]
    with BagWriter(tmp_path / "bag") as w:
        for ns, raw in data:
            w.write_serialized(topics.JOINT_STATES, ns, raw)
        assert w.counts == {topics.JOINT_STATES: 5}
    assert [(ns, raw) for _, ns, raw, _ in bagio.iter_bag_messages(tmp_path / "bag")] == data
