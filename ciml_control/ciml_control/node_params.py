"""Parameter schemas of the ciml_control nodes (ciml_learning.core.params): each is the one source
of the node's declare() calls, its config/<node>.yaml and its README table."""
from __future__ import annotations

from ciml_learning.core.params import NodeSchema, Param
from ciml_learning.learning.rollback import RollbackConfig
from ciml_learning.ros.node_params import ROBOT, THREAD_PRIORITY

from .feedback import BASE_ANGULAR_KD, BASE_ANGULAR_KP, BASE_LINEAR_KD, BASE_LINEAR_KP
from .references import MOTIONS
from .trust import DEFAULT_MAX_VARIANCE_RATIO

_ROLLBACK = RollbackConfig()

REFERENCE_GENERATOR = NodeSchema("ciml_control", "reference_generator",
                                 "the full-body reference of a motion on /reference", (
    Param("motion", "stand", "Motion to generate", choices=MOTIONS, deploy="trot_35"),
    Param("rate", 250.0, "Publish rate", "Hz", 1.0, 1000.0, read_only=False),
    Param("start_on_command", True, "Start the motion once the robot is under torque control (the first "
          "MODE_TORQUE /torque_command); false: at the node's start"),
    Param("start_delay", 1.0, "Standing time under the controller before the motion starts (node clock)", "s",
          0.0, 60.0),
    Param("foot_height", 0.002, "Height of the foot frames above the ground when standing (sphere foot radius "
          "of the simulation)", "m", 0.0, 0.2),
    Param("lookahead", 0.008, "Each /reference is published this long before its stamp (the motion sampled "
          "ahead), so the controller and the model server hold the reference of a robot sample's own instant "
          "when the sample arrives (two periods: one for the model server's prediction; 0: stamped now, one "
          "period behind the sample that uses it)", "s", 0.0, 0.1,
          read_only=False),
    THREAD_PRIORITY,
    ROBOT,
))

ID_CONTROLLER = NodeSchema("ciml_control", "id_controller",
                           "the inverse-dynamics QP controller (eq. 17-24) with the predicted model error ε", (
    Param("rate", 250.0, "Watchdog rate (control runs on each /joint_states sample)", "Hz", 10.0, 1000.0),
    Param("state_timeout", 0.05, "Damping when a state topic is older than this (node clock; use_sim_time:=true "
          "with a simulator)", "s", 0.002, 2.0, read_only=False),
    Param("reference_timeout", 0.1, "A /reference older than this is stale: safe stop (the swing feet land, then the "
          "robot stands; ciml_control.safe_stop)", "s", 0.004, 5.0, read_only=False),
    Param("landing_time", 0.2, "Safe stop: time for the swing feet to reach the ground", "s", 0.02, 2.0),
    Param("resume_tolerance", 0.02, "Safe stop: a fresh /reference is tracked again only if its base is within this "
          "of the pose the robot stopped at (else the robot stands until the motion restarts)", "m", 0.0, 1.0),
    Param("wait_for_reference", False, "With a simulator in lockstep: a joint sample whose /reference is older than "
          "reference_timeout, or stamped more than max_reference_lag before it, is answered once a fresh one arrives "
          "(the simulation waits for the reference node as it waits for this one) instead of the safe stop",
          read_only=False),
    Param("max_reference_lag", 0.02, "wait_for_reference: the most a /reference's stamp may lag the joint sample's "
          "(more than the reference's period; a late reference then costs at most its speed times this, below "
          "resume_tolerance at trot speed)", "s", 0.004, 1.0, read_only=False),
    Param("reference_hold", 0.5, "Damping when /reference is older than this (≤ reference_timeout: at once)", "s",
          0.0, 10.0, read_only=False),
    Param("model_error_timeout", 0.1, "Nominal model (ε = 0) when the newest prediction is older than this", "s",
          0.004, 5.0, read_only=False),
    Param("max_prediction_lag", 0.02, "Nominal model when the newest prediction was made for a reference stamped "
          "further than this from the reference in use", "s", 0.0, 1.0, read_only=False),
    Param("use_model_error", True, "Add the predicted model error ε (eq. 17) to the QP", read_only=False),
    Param("damping_gain", 0.0, "Joint damping of the safe mode (0 = derived from the robot: 10 Nm s/rad scaled by "
          "its mass, standing.safe_damping_gain)", "Nm s/rad", 0.0, 200.0, read_only=False),
    Param("kp", 0.0, "Joint PD stiffness of the 1 kHz loop (0 = derived from the robot: 300 Nm/rad scaled by its "
          "mass, feedback.joint_gain_scale)", "Nm/rad", 0.0, 2000.0, read_only=False),
    Param("kd", 0.0, "Joint PD damping of the 1 kHz loop (0 = derived, as kp: 8 Nm s/rad scaled)", "Nm s/rad", 0.0,
          200.0, read_only=False),
    Param("base_kp_linear", BASE_LINEAR_KP, "Feedback linearisation gain, base position (eq. 24)", "1/s²", 0.0, 2000.0,
          read_only=False),
    Param("base_kp_angular", BASE_ANGULAR_KP, "Feedback linearisation gain, base orientation", "1/s²", 0.0, 2000.0,
          read_only=False),
    Param("base_kd_linear", BASE_LINEAR_KD, "Feedback linearisation gain, base velocity", "1/s", 0.0, 200.0,
          read_only=False),
    Param("base_kd_angular", BASE_ANGULAR_KD, "Feedback linearisation gain, base angular velocity", "1/s", 0.0, 200.0,
          read_only=False),
    Param("joint_lin_kp", 0.0, "Feedback linearisation gain, joints", "1/s²", 0.0, 2000.0, read_only=False),
    Param("joint_lin_kd", 0.0, "Feedback linearisation gain, joint velocities", "1/s", 0.0, 200.0, read_only=False),
    Param("mu", 0.5, "Friction coefficient of the QP's octagon cone", "", 0.05, 2.0, read_only=False),
    Param("f_min", 5.0, "Smallest normal force of a stance foot in the QP", "N", 0.0, 500.0, read_only=False),
    Param("feedback_contacts", "reference", "Contact set of the feedback projector", choices=("reference", "measured"),
          read_only=False),
    Param("max_variance_ratio", DEFAULT_MAX_VARIANCE_RATIO, "Use a predicted model-error entry only if its variance "
          "is at most this × the nominal prior variance", "", 1e-3, 1e3, read_only=False),
    Param("rollback", True, "Roll back a newly served model whose feedback effort or base position error rises "
          "beyond rollback_rise × its predecessor's, or whose effort is more than rollback_worse above it "
          "(ciml_learning.learning.rollback)", read_only=False),
    Param("rollback_window", _ROLLBACK.window, "RMS window of a newly served model's effort and error", "s", 0.02,
          5.0),
    Param("rollback_probation", _ROLLBACK.probation, "A newly served model is watched this long", "s", 0.1, 600.0),
    Param("rollback_rise", _ROLLBACK.rise, "Rollback above this × the RMS of the seconds before the model (plus "
          "a tenth of the robot's largest joint torque limit, 3 cm)", "", 1.0, 10.0),
    Param("rollback_assess", _ROLLBACK.assess, "A newly served model's RMS effort over this long is compared with "
          "the seconds before it (≤ rollback_probation)", "s", 0.1, 600.0),
    Param("rollback_worse", _ROLLBACK.worse, "Rollback when that RMS effort is more than this share above the "
          "seconds before the model", "", 0.0, 10.0),
    Param("effort_command_topic", "", "Also publish each command as the joint torque u of the joint-loop law at "
          "its sample [Nm], clipped to the limits, in a std_msgs/Float64MultiArray on this topic, for a ros2_control "
          "effort forward_command_controller ('<controller>/commands'); joint order: the profile's command joints "
          "when it is such an array, else the robot's ('' = not published)"),
    Param("feedforward_only", False, "Command nothing (no /torque_command): compute the learned correction, the "
          "QP feedforward with ε minus without, and publish it on /model_error/feedforward for the robot's own "
          "controller"),
    THREAD_PRIORITY,
    ROBOT,
))

SCHEMAS: tuple[NodeSchema, ...] = (REFERENCE_GENERATOR, ID_CONTROLLER)
