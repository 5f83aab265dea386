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

STATE_FILTER = NodeSchema("ciml_learning", "state_filter", "raw sensor topics → /filtered_state (the online filter of paper §III-C)", (
    Param("rate", 0.0, "Rate of /joint_states the filter is designed for (0: measured from the stamps of the "
          "first samples)", "Hz", 0.0, 2000.0),
    Param("max_age", 0.02, "Oldest base/contact/command sample paired with a joint sample", "s", 0.001, 1.0,
          read_only=False),
    URDF,
))

ERROR_EXTRACTOR = NodeSchema("ciml_learning", "error_extractor", "/filtered_state → /model_error/measured (eq. 11 and 14)", (
    Param("gamma", 0.02, "Regularisation of near-singular leg blocks", "m/rad", 1e-4, 0.2, read_only=False),
    URDF,
))

MODEL_SERVER = NodeSchema("ciml_learning", "model_server", "/reference → /model_error/predicted (ε of eq. 17) from the served model", (
    Param("model_dir", "", "Model folder served at start ('' = nominal model until a /model_update)"),
    Param("swap_check_period", 0.02, "How often a model loaded in the background is swapped in", "s", 0.001, 1.0),
    URDF,
))

SCHEMAS: tuple[NodeSchema, ...] = (STATE_FILTER, ERROR_EXTRACTOR, MODEL_SERVER, STATE_PUBLISHER)
