"""`ciml diagnose --publish`: the GapDiagnosis summary of a finished diagnosis on /gap_diagnosis.

The diagnosis itself stays rclpy-free (ciml_learning.diagnosis); this adapter maps its result
(the dict written to diagnosis.json) to ciml_msgs/GapDiagnosis and publishes it once, transient
local, so a dashboard that connects while the publisher is up still receives it.
"""
from __future__ import annotations

import math
import os
import time
from typing import Any


def _num(x: Any) -> float:
    return float(x) if x is not None else math.nan


def gap_diagnosis_fields(result: dict) -> dict[str, Any]:
    """The GapDiagnosis fields of a diagnosis result (ciml_learning.diagnosis.run.diagnose)."""
    from ciml_learning.diagnosis.report import effect_location

    loc = result["localization"]
    effects = result["effects"]
    shrink = result.get("shrink") or {}
    return {
        "dimension_names": [str(d["dimension"]) for d in loc],
        "dimension_rms_error": [_num(d["rms_error"]) for d in loc],
        "dimension_share": [_num(d["share"]) for d in loc],
        "effect_types": [str(e["type"]) for e in effects],
        "effect_locations": [str(effect_location(e)) for e in effects],
        "effect_share": [_num(e["share"]) for e in effects],
        "unexplained_share": _num(result["unexplained_share"]),
        "heldout_rms_nominal": _num(shrink.get("heldout_rms_nominal")),
        "heldout_rms_with_effects": _num(shrink.get("heldout_rms_with_effects")),
        "shrink_ratio": _num(shrink.get("ratio")),
    }


def publish_gap_diagnosis(result: dict, linger: float = 5.0, frame_id: str = "") -> int:
    """Publish the summary once on /gap_diagnosis (transient local) and keep the publisher up for
    `linger` seconds so subscribers that join meanwhile receive it; return the number of
    subscribers matched when it ended."""
    import rclpy
    from ciml_msgs.msg import GapDiagnosis

    from ciml_learning.core import topics
    from ciml_learning.ros.ros_common import LATCHED_QOS

    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    try:
        node = rclpy.create_node("ciml_diagnose", context=ctx)
        pub = node.create_publisher(GapDiagnosis, topics.GAP_DIAGNOSIS, LATCHED_QOS)
        msg = GapDiagnosis(**gap_diagnosis_fields(result))
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.header.frame_id = frame_id
        pub.publish(msg)
        end = time.monotonic() + linger
        matched = 0
        try:
            while time.monotonic() < end and ctx.ok():  # DDS serves late joiners from its own threads
                matched = max(matched, pub.get_subscription_count())
                time.sleep(0.1)
        except KeyboardInterrupt:  # Ctrl-C ends the wait; the diagnosis is written already
            pass
        return matched
    finally:
        rclpy.try_shutdown(context=ctx)
