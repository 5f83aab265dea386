"""rosbag2 bags with rosbags: the typestore, writing MCAP bags, reading robot logs.

- The typestore is ROS 2 Jazzy's plus ciml_msgs registered from the .msg files
  themselves (the installed share/ciml_msgs/msg, else the source tree): one source.
- Writing: messages are rclpy objects serialised by rclpy (byte-identical to what the
  live graph publishes) and stored with rosbags' MCAP writer; no DDS is involved.
- Reading: samples are ordered by header.stamp, never by receive time (docs/ARCHITECTURE.md §7);
  truncated or incomplete bags become one-line BagErrors. A robot log is read through
  its robot profile by loginputs.load_log: MCAP, db3 and ROS 1 bags, any layout.
"""
from __future__ import annotations

import glob
import os
import sys
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ciml_learning.core import topics
from ciml_learning.core.conversions import stamp_to_ns
from ciml_learning.core.errors import CimlError

if TYPE_CHECKING:  # for the annotation only: rosbags is imported where it is used, as elsewhere here
    from rosbags.interfaces import Connection


class BagError(CimlError):
    """A bag cannot be read or does not hold a usable robot log."""


def msg_dir() -> str:
    """Folder holding ciml_msgs' .msg files: an ament prefix (AMENT_PREFIX_PATH, this venv), else the source tree."""
    prefixes = [p for p in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p] + [sys.prefix]
    candidates = [os.path.join(p, "share", "ciml_msgs", "msg") for p in prefixes]
    candidates.append(os.path.join(os.path.dirname(__file__), "..", "..", "..", "ciml_msgs", "msg"))
    for d in candidates:
        if glob.glob(os.path.join(d, "*.msg")):
            return os.path.abspath(d)
    raise BagError("ciml_msgs .msg files not found; run make install")


@lru_cache(maxsize=1)
def typestore():
    """ROS 2 Jazzy typestore with every ciml_msgs type registered from its .msg text."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted(glob.glob(os.path.join(msg_dir(), "*.msg"))):
        name = f"ciml_msgs/msg/{Path(path).stem}"
        types.update(get_types_from_msg(Path(path).read_text(encoding="utf-8"), name))
    store.register(types)
    return store


COMPRESSIONS = ("none", "zstd")
"""MCAP chunk compressions BagWriter writes (`compression=`)."""


MOTION_KEY = "ciml.motion"
"""custom_data key of metadata.yaml naming the motion a simulated log runs (`ciml record` writes it;
`ciml verify` re-simulates that motion). Stamps of such a log are time since the motion started."""


def custom_data(path: str | os.PathLike) -> dict[str, str]:
    """metadata.yaml's custom_data of a rosbag2 folder ({} for a bag without one, or a ROS 1 bag)."""
    from ciml_learning.core.fileio import load_yaml_bounded

    meta = Path(path) / "metadata.yaml"
    if not meta.is_file():
        return {}
    info = load_yaml_bounded(str(meta), "bag metadata")
    data = (info.get("rosbag2_bagfile_information") or {}).get("custom_data") if isinstance(info, dict) else None
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}


class BagWriter:
    """Write rclpy messages into a new rosbag2 MCAP bag (atomically: temp dir + rename).

    compression: "none" (default) or "zstd" — standard MCAP chunk compression, as
    rosbag2's MCAP storage presets `zstd_fast`/`zstd_small` write it (rosbags' storage
    compression mode; MCAP readers such as ros2 bag, Foxglove and rosbags decompress
    chunks themselves), and metadata.yaml still says compression_mode "" (the
    compression is inside the MCAP file). Bags of the simulation shrink ~4× (names
    repeat in every message). The default writes plain chunks.
    """

    def __init__(self, path: str | os.PathLike, compression: str | None = None,
                 custom_data: dict[str, str] | None = None) -> None:
        """custom_data: metadata.yaml's custom_data (rosbag2's free key → string map), e.g. the
        recorded motion (MOTION_KEY)."""
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

        compression = "none" if compression is None else compression
        if compression not in COMPRESSIONS:
            raise BagError(f"bag compression {compression!r} is not supported; valid: {', '.join(COMPRESSIONS)}")
        self.compression = compression
        self.path = Path(path)
        if os.path.lexists(self.path):
            raise BagError(f"{self.path} exists already; choose a new --out")
        from ciml_learning.core.fileio import check_out_parent, clean_stale, temp_sibling

        check_out_parent(str(self.path), "--out")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale(str(self.path))  # folders of killed recordings
        self._tmp = Path(temp_sibling(str(self.path), "partial"))
        if self._tmp.exists():
            import shutil

            shutil.rmtree(self._tmp)
        self._writer = Writer(self._tmp, version=9, storage_plugin=StoragePlugin.MCAP)
        if compression == "zstd":
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        for key, value in (custom_data or {}).items():
            self._writer.set_custom_data(key, value)
        self._connections: dict[str, Connection] = {}
        self.counts: dict[str, int] = {}

    def __enter__(self) -> "BagWriter":
        self._writer.open()
        return self

    def write(self, topic: str, stamp_ns: int, msg, msgtype: str | None = None) -> None:
        """Append one rclpy message; `msgtype` defaults to the graph's type of `topic`."""
        from rclpy.serialization import serialize_message

        self.write_serialized(topic, stamp_ns, serialize_message(msg), msgtype)

    def write_serialized(self, topic: str, stamp_ns: int, data: bytes, msgtype: str | None = None) -> None:
        """Append one message already CDR-serialised (as rclpy's serialize_message gives it,
        e.g. ciml_sim.serialized); `msgtype` defaults to the graph's type of `topic`."""
        conn = self._connections.get(topic)
        if conn is None:
            msgtype = msgtype or topics.topic_type(topic)
            conn = self._writer.add_connection(topic, msgtype, typestore=typestore())
            self._connections[topic] = conn
        self._writer.write(conn, int(stamp_ns), data)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            import shutil

            try:
                self._writer.close()
            finally:
                shutil.rmtree(self._tmp, ignore_errors=True)
            return
        self._finish()

    def _finish(self) -> None:
        """Complete the bag inside its temporary folder — the MCAP under its final name,
        metadata.yaml naming it, every CRC written (mcap_check.seal_mcap) — then publish the
        folder with one rename: a kill at any point leaves no bag or the whole bag at `path`
        (the folder's own name is recorded nowhere inside)."""
        import shutil

        from ciml_learning.core.fileio import OutputError, fault_point, publish_dir
        from ciml_learning.logs.mcap_check import seal_mcap

        try:
            self._writer.close()
            meta = self._tmp / "metadata.yaml"
            text = meta.read_text(encoding="utf-8")
            for i, m in enumerate(sorted(self._tmp.glob("*.mcap"))):
                new = f"{self.path.name}_{i}.mcap"
                fault_point("rename")
                m.rename(self._tmp / new)
                text = text.replace(m.name, new)
                seal_mcap(self._tmp / new)
            fault_point("write")
            meta.write_text(text, encoding="utf-8")
            if os.path.lexists(self.path):
                raise BagError(f"{self.path} appeared while recording; the recording is discarded")
            publish_dir(str(self._tmp), str(self.path.absolute()))
        except OutputError as err:
            raise BagError(str(err)) from None
        finally:
            shutil.rmtree(self._tmp, ignore_errors=True)


ROS1_MAGIC = b"#ROSBAG V2.0\n"
"""First bytes of a ROS 1 bag file (format 2.0, the only one ROS 1 writes)."""


def is_ros1_bag(path: Path) -> bool:
    """A file that starts as a ROS 1 bag, whatever its name."""
    try:
        with open(path, "rb") as f:
            return path.is_file() and f.read(len(ROS1_MAGIC)) == ROS1_MAGIC
    except OSError:
        return False


def open_reader(paths: Sequence[str | os.PathLike]):
    import shutil
    import tempfile

    from rosbags.highlevel import AnyReader, AnyReaderError

    bags = [Path(p) for p in paths]
    for p in bags:
        if not p.exists():
            raise BagError(f"bag not found: {p}")
    from ciml_learning.logs.mcap_check import BagCorruptError, check_bag

    try:  # CRCs and framing before any byte is decoded (mcap_check)
        for p in bags:
            check_bag(p)
    except BagCorruptError as err:
        raise BagError(str(err)) from None
    # rosbags tells a ROS 1 bag by its .bag suffix: a renamed one is read through a link that has it
    # (the reader holds the file open, so the link goes once it is open)
    ros1 = [i for i, p in enumerate(bags) if p.suffix != ".bag" and is_ros1_bag(p)]
    links = tempfile.mkdtemp(prefix="ciml-ros1-") if ros1 else None
    opened = list(bags)
    for i in ros1:
        opened[i] = Path(str(links)) / f"{i}_{bags[i].name}.bag"
        opened[i].symlink_to(bags[i].resolve())
    try:
        reader = AnyReader(opened, default_typestore=typestore())
        reader.open()
    except AnyReaderError as err:
        fix = ("'rosbag reindex' (ROS 1)" if all(p.suffix == ".bag" for p in opened)
               else "'ros2 bag reindex' (db3) or 'mcap recover' (MCAP)")
        raise BagError(f"cannot read bag {', '.join(map(str, bags))}: {err} — if it was cut short, try {fix}") from err
    except FileNotFoundError as err:
        missing = os.path.basename(err.filename) if err.filename else "metadata.yaml"
        raise BagError(
            f"bag {', '.join(map(str, bags))}: {missing} is missing; "
            "recreate metadata.yaml with 'ros2 bag reindex'"
        ) from None
    finally:
        if links is not None:
            shutil.rmtree(links, ignore_errors=True)
    return reader


def list_topics(path: str | os.PathLike) -> dict[str, str]:
    """Topic → message type of one bag."""
    reader = open_reader([path])
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def read_messages(path: str | os.PathLike, wanted: Iterable[str]) -> dict[str, list[tuple[int, object]]]:
    """Messages of the wanted topics of one bag as (header stamp [ns], msg), sorted by stamp.

    Raises BagError for a truncated bag; a missing topic gives an empty list.
    """
    from rosbags.highlevel import AnyReaderError

    wanted = set(wanted)
    reader = open_reader([path])
    out: dict[str, list[tuple[int, object]]] = {t: [] for t in wanted}
    try:
        conns = [c for c in reader.connections if c.topic in wanted]
        for conn, log_ns, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            header = getattr(msg, "header", None)
            stamp = stamp_to_ns(header.stamp) if header is not None else log_ns
            out[conn.topic].append((stamp, msg))
    except (AnyReaderError, EOFError, ValueError, KeyError) as err:
        raise BagError(
            f"bag {path} is truncated or corrupt ({type(err).__name__}: {err}); "
            "try 'mcap recover' (MCAP) or 'ros2 bag reindex' (db3)"
        ) from err
    finally:
        reader.close()
    for msgs in out.values():
        msgs.sort(key=lambda m: m[0])  # stable: equal sim-time stamps keep bag order
    return out


@dataclass
class SensorLog:
    """A robot log as arrays, one row per joint-state sample, in the robot's orders.

    q: (N × nq) Pinocchio configuration; v: (N × nv), base twist in the base frame; tau:
    measured torques; u: total commanded torques (joint loop, TorqueCommand.msg; equal to
    tau when no command is logged, u_observed False); contacts: (N × n_feet).
    rate_hz: measured from the joint-state stamps (median period); stamp_report: their
    problems (stamps.StampReport, plus age-limit misses per role); sources: where each
    role came from or how it was estimated; warnings: what the log cannot show (e.g. the
    measured torque follows the command).
    """

    bag: str
    t: np.ndarray
    q: np.ndarray
    v: np.ndarray
    tau: np.ndarray
    u: np.ndarray
    contacts: np.ndarray
    rejected: dict[str, int] = field(default_factory=dict)
    rate_hz: float = float("nan")
    stamp_report: dict = field(default_factory=dict)
    u_observed: bool = True
    sources: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    torque_command_correlation: dict[str, float | None] | None = None

    def __len__(self) -> int:
        return len(self.t)


def first_message(path: str | os.PathLike, topic: str) -> tuple[int, Any] | None:
    """(header stamp [ns], message) of the first message of `topic` in log order, or None without one."""
    reader = open_reader([path])
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:  # rosbags reads every topic for an empty list
            return None
        for conn, log_ns, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            header = getattr(msg, "header", None)
            return (stamp_to_ns(header.stamp) if header is not None else log_ns), msg
        return None
    finally:
        reader.close()


def iter_bag_messages(path: str | os.PathLike) -> Iterator[tuple[str, int, bytes, str]]:
    """All messages of a bag as (topic, log time [ns], raw CDR, type), in log-time order (for replay)."""
    reader = open_reader([path])
    try:
        for conn, log_ns, raw in reader.messages():
            yield conn.topic, log_ns, bytes(raw), conn.msgtype
    finally:
        reader.close()
