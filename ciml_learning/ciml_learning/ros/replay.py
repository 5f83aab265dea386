"""`ciml play`: publish a bag's topics onto the live graph with their recorded timing.

For machines without `ros2 bag`. Messages are published as the raw CDR bytes stored
in the bag (no re-serialisation), paced by their log times scaled by 1/rate.
/sim/ ground-truth topics are replayed too unless excluded; QoS follows the graph's
conventions (sensor topics best effort, everything else reliable).
"""
from __future__ import annotations

import importlib
import time
from collections.abc import Iterable

from ciml_learning.core import topics
from ciml_learning.logs.bagio import BagError, iter_bag_messages, list_topics


def message_class(msgtype: str):
    """'pkg/msg/Name' → the rclpy message class."""
    pkg, kind, name = msgtype.split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ImportError, AttributeError) as err:
        raise BagError(f"message type {msgtype} is not installed in this environment") from err


def play_bag(path: str, rate: float = 1.0, exclude_prefixes: Iterable[str] = (), node_name: str = "ciml_play",
             progress: bool = True, wait_subscribers: float = 3.0) -> dict[str, int]:
    """Publish every message of the bag at its recorded time; return counts per topic."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    from ciml_learning.ros.ros_common import COMMAND_QOS, SENSOR_PUB_QOS

    if not rate > 0:
        raise BagError(f"--rate must be > 0, got {rate}")
    exclude = tuple(exclude_prefixes)
    types = {t: ty for t, ty in list_topics(path).items() if not t.startswith(exclude)}
    rclpy.init()
    counts: dict[str, int] = {t: 0 for t in types}
    try:
        node = rclpy.create_node(node_name)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        pubs = {
            t: node.create_publisher(message_class(ty), t,
                                     SENSOR_PUB_QOS if t in topics.MEASUREMENT_TOPICS else COMMAND_QOS)
            for t, ty in types.items()
        }
        # give discovery up to `wait_subscribers` s to match subscribers before the first message
        deadline = time.monotonic() + wait_subscribers
        measured = [p for p in pubs.values() if types[p.topic_name] and p.topic_name in topics.MEASUREMENT_TOPICS]
        while time.monotonic() < deadline and not all(p.get_subscription_count() for p in measured):
            executor.spin_once(timeout_sec=0.05)
        time.sleep(0.3)
        start_wall = None
        start_log = 0  # log time of the first message played (set with start_wall)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(desc="play", unit="msg", leave=False)
        for topic, log_ns, raw, _ in iter_bag_messages(path):
            if topic not in pubs:
                continue
            if start_wall is None:
                start_wall, start_log = time.monotonic(), log_ns
            due = start_wall + (log_ns - start_log) * 1e-9 / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            pubs[topic].publish(raw)
            counts[topic] += 1
            if bar is not None:
                bar.update()
        if bar is not None:
            bar.close()
        time.sleep(0.2)  # let the last messages leave
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return counts
