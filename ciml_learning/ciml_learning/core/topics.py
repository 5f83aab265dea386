"""Topic names and message types of the CIML graph (docs/ARCHITECTURE.md §3) — defined once.

Live nodes, `ciml record` and the bag readers all take names from here, so a bag
recorded headless has exactly the live graph's topics and types.
"""
from __future__ import annotations

JOINT_STATES = "/joint_states"
BASE_STATE = "/base_state"
CONTACT_STATE = "/contact_state"
TORQUE_COMMAND = "/torque_command"
CLOCK = "/clock"
FILTERED_STATE = "/filtered_state"
MODEL_ERROR_MEASURED = "/model_error/measured"
LEARNING_SAMPLES = "/model_error/learning_samples"
"""error_extractor → online_learner: the valid states with their measured errors, nothing else."""
MODEL_ERROR_PREDICTED = "/model_error/predicted"
MODEL_ERROR_FEEDFORWARD = "/model_error/feedforward"
"""id_controller with feedforward_only: the learned joint-torque correction (sensor_msgs/JointState effort)."""
MODEL_UPDATE = "/model_update"
MODEL_ROLLBACK = "/model_rollback"
"""The controller's request to stop serving a model (std_msgs/String: the model's `source` name)."""
REFERENCE = "/reference"
DIAGNOSTICS = "/diagnostics"
TF = "/tf"
TF_STATIC = "/tf_static"
ROBOT_DESCRIPTION = "/robot_description"
"""The URDF text (std_msgs/String, transient local), as robot_state_publisher publishes it."""
GAP_DIAGNOSIS = "/gap_diagnosis"
"""`ciml diagnose --publish`: the diagnosis summary, once, transient local."""

SIM_PREFIX = "/sim/"
"""Simulation-only ground truth. Never read by learning or diagnosis code."""
SIM_ACCELERATION = "/sim/acceleration"
SIM_CONTACT_FORCES = "/sim/contact_forces"
SIM_EFFECT_PREFIX = "/sim/effect/"

TYPES: dict[str, str] = {
    JOINT_STATES: "sensor_msgs/msg/JointState",
    BASE_STATE: "nav_msgs/msg/Odometry",
    CONTACT_STATE: "ciml_msgs/msg/ContactState",
    TORQUE_COMMAND: "ciml_msgs/msg/TorqueCommand",
    CLOCK: "rosgraph_msgs/msg/Clock",
    FILTERED_STATE: "ciml_msgs/msg/RobotState",
    MODEL_ERROR_MEASURED: "ciml_msgs/msg/ModelError",
    LEARNING_SAMPLES: "ciml_msgs/msg/LearningSample",
    MODEL_ERROR_PREDICTED: "ciml_msgs/msg/ModelError",
    MODEL_ERROR_FEEDFORWARD: "sensor_msgs/msg/JointState",
    MODEL_UPDATE: "ciml_msgs/msg/ModelUpdate",
    MODEL_ROLLBACK: "std_msgs/msg/String",
    REFERENCE: "ciml_msgs/msg/RobotReference",
    DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray",
    TF: "tf2_msgs/msg/TFMessage",
    TF_STATIC: "tf2_msgs/msg/TFMessage",
    ROBOT_DESCRIPTION: "std_msgs/msg/String",
    GAP_DIAGNOSIS: "ciml_msgs/msg/GapDiagnosis",
    SIM_ACCELERATION: "ciml_msgs/msg/GeneralizedForce",
    SIM_CONTACT_FORCES: "ciml_msgs/msg/ContactForces",
}

SENSOR_TOPICS: tuple[str, ...] = (JOINT_STATES, BASE_STATE, CONTACT_STATE, TORQUE_COMMAND)
"""What a robot log must contain to learn from it (no force sensors needed)."""
MEASUREMENT_TOPICS: tuple[str, ...] = (JOINT_STATES, BASE_STATE, CONTACT_STATE)
"""Sensor topics: published reliable (depth 10) so default-QoS readers match; our nodes read them best effort."""


def topic_type(topic: str) -> str:
    """Message type of a topic; every /sim/effect/<label> is a GeneralizedForce."""
    if topic.startswith(SIM_EFFECT_PREFIX):
        return "ciml_msgs/msg/GeneralizedForce"
    return TYPES[topic]


def is_ground_truth(topic: str) -> bool:
    return topic.startswith(SIM_PREFIX)
