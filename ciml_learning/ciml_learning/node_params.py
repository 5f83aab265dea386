"""Parameter schemas of the ciml_learning nodes (ciml_learning.params): each is the one
source of the node's declare() calls, its config/<node>.yaml and its README table."""
from __future__ import annotations

from .params import NodeSchema, Param

URDF = Param("urdf", "", "Robot URDF ('' = HyQ from example-robot-data)")

STATE_PUBLISHER = NodeSchema("ciml_learning", "state_publisher", "/tf, /tf_static and /robot_description from /base_state and /joint_states", (
    Param("publish_rate", 50.0, "Most /tf messages per second (each /joint_states and /base_state sample at most this often)",
          "Hz", 1.0, 1000.0, read_only=False),
    Param("odom_frame", "", "Parent frame of the base ('' = the frame_id of /base_state)"),
    URDF,
))

SCHEMAS: tuple[NodeSchema, ...] = (STATE_PUBLISHER,)
