"""Parameter schemas of the ciml_learning nodes (ciml_learning.core.params): each is the one
source of the node's declare() calls, its config/<node>.yaml and its README table."""
from __future__ import annotations

from dataclasses import replace

from ciml_learning.core.params import NodeSchema, Param
from ciml_learning.learning.learning_gate import MAX_REFERENCE_AGE, GateConfig
from ciml_learning.learning.snapshot_gate import ValidationConfig
from ciml_learning.ros import realtime

ROBOT = Param("robot", "hyq", "Robot profile: a profile YAML path or a shipped robot's name (hyq, go1, solo12, a1; "
              "docs/ROBOT_PROFILE.md); every node of a graph must name the same robot")
"""Every node's robot, declared here once (profile.load_profile reads it: URDF, feet, torque limits).
It replaces the nodes' former `urdf` parameter, whose feet fell back to HyQ's: a URDF alone does not
say which frames are the feet."""
THREAD_PRIORITY = Param(realtime.THREAD_PRIORITY, 50, "SCHED_FIFO priority of the node's process (0 = normal "
                        "scheduling; without the right to, a warning and normal scheduling, as ros2_control)",
                        "", 0, 98)
"""The control path's (bridge, reference generator, controller) at 50; the model server's at 20
(its predictions feed the controller at the reference's rate; its model loads run normally
scheduled); the state filter's at 0 (normally scheduled, niced by the launch file): the kernel
lets SCHED_FIFO take at most 95 % of each second (sched_rt_runtime_us), and with the learning
container real-time too the graph's real-time work on two cores met that cap and stalled for
0.4–2.4 s (results/LIVE_GRAPH.md): ciml_learning.ros.realtime."""

STATE_PUBLISHER = NodeSchema("ciml_learning", "state_publisher",
                             "/tf, /tf_static and /robot_description from /base_state and /joint_states", (
    Param("publish_rate", 50.0, "Most /tf messages per second (each /joint_states and /base_state sample at most "
          "this often)", "Hz", 1.0, 1000.0, read_only=False),
    Param("odom_frame", "", "Parent frame of the base ('' = the frame_id of /base_state)"),
    ROBOT,
))

STATE_FILTER = NodeSchema("ciml_learning", "state_filter",
                          "raw sensor topics → /filtered_state (the online filter of paper §III-C)", (
    Param("rate", 0.0, "Rate of /joint_states the filter is designed for (0: measured from the stamps of the "
          "first samples)", "Hz", 0.0, 2000.0),
    Param("max_age", 0.02, "Oldest base/contact/command sample paired with a joint sample", "s", 0.001, 1.0,
          read_only=False),
    Param("inputs", "profile", "Topics read: the robot profile's input map (a robot's own driver or a replay of "
          "its log) or CIML's own (/joint_states, /base_state, /contact_state, /torque_command, as the simulator "
          "bridge publishes them for any robot)", choices=("profile", "ciml")),
    replace(THREAD_PRIORITY, default=0),
    ROBOT,
))

ERROR_EXTRACTOR = NodeSchema("ciml_learning", "error_extractor",
                             "/filtered_state → /model_error/measured (eq. 11 and 14) and, for states with a "
                             "usable part, /model_error/learning_samples", (
    Param("gamma", 0.02, "Regularisation of near-singular leg blocks", "m/rad", 1e-4, 0.2, read_only=False),
    Param("batch_period", 0.02, "Filtered states are extracted together every this often (wall clock); one state "
          "costs ~0.7 ms alone, ~0.2 ms in a batch of 5 (0: each state at once)", "s", 0.0, 0.5, read_only=False),
    Param("max_reference_age", MAX_REFERENCE_AGE, "Largest stamp distance between a state and the /reference "
          "sample sent with its learning sample", "s", 0.001, 1.0),
    Param("max_pair_age", 0.5, "Longest wait of a learning sample for the /reference of its instant (in stamps "
          "behind the newest sample)", "s", 0.004, 10.0),
    Param("effort_sample_every", 4, "Of the states whose torques are usable but not the rigid-body error (near a "
          "contact change: most of a trot), every this-th goes to the learner, for Γ only (1: all; 0: none): the "
          "learner's share of the CPU bounds how many it can take", "", 0, 1000),
    ROBOT,
))

MODEL_SERVER = NodeSchema("ciml_learning", "model_server",
                          "/reference → /model_error/predicted (ε of eq. 17) from the served model", (
    Param("model_dir", "", "Model folder served at start ('' = nominal model until a /model_update)"),
    Param("swap_check_period", 0.02, "How often a model loaded in the background is swapped in", "s", 0.001, 1.0),
    Param("min_serve_time", 6.0, "A loaded model waits until the one serving has served this long (reference stamps; "
          "≥ the controller's rollback_assess, so every served model is assessed; 0 = at once)", "s", 0.0, 600.0),
    replace(THREAD_PRIORITY, default=20),
    ROBOT,
))

_GATE = GateConfig()
_VALIDATION = ValidationConfig()
ONLINE_LEARNER = NodeSchema("ciml_learning", "online_learner",
                            "learns the model error from /model_error/learning_samples; "
                            "snapshots announced on /model_update", (
    Param("model_dir", "", "Snapshot folder ('' = ~/.ros/ciml/online_model; snapshot-NNNNNN/, latest -> newest)"),
    Param("snapshot_period", 5.0, "Seconds between model snapshots (only when something new was learned)", "s",
          0.1, 3600.0),
    Param("keep_snapshots", 3, "Snapshot folders kept (older ones are deleted)", "", 1, 1000),
    Param("learner", "lwpr", "Incremental learner of the model set (partial_fit; the sparse GP is batch-only)",
          choices=("lwpr",)),
    Param("initial_model", "", "Model folder to continue learning from ('' = empty model set)"),
    Param("calibration_samples", 0, "Valid samples buffered to calibrate input/output scaling first "
          "(0 = default scaling)", "", 0, 100000),
    Param("queue_depth", 250, "Subscription queue depth (absorbs snapshot stalls; ≥ 1 s of learning samples at "
          "250 Hz)", "", 10, 10000),
    Param("record_stamps", False, "Write the learned samples' stamps (learned_stamps.npy) into each snapshot"),
    Param("min_height_ratio", _GATE.min_height_ratio, "Pause learning (fall) below this fraction of the standing "
          "base height", "", 0.05, 1.0),
    Param("max_tilt", _GATE.max_tilt, "Pause learning (fall) above this base tilt", "rad", 0.01, 3.14),
    Param("max_position_error", _GATE.max_position_error, "Pause learning above this base position error to "
          "/reference", "m", 0.001, 10.0),
    Param("max_attitude_error", _GATE.max_attitude_error, "Pause learning above this attitude error to /reference",
          "rad", 0.001, 3.14),
    Param("max_joint_error", _GATE.max_joint_error, "Pause learning above this RMS joint error to /reference", "rad",
          0.001, 3.14),
    Param("resume_after", _GATE.resume_after, "Resume learning after the checks passed this long (stamps)", "s",
          0.0, 60.0),
    Param("bound_scale", _GATE.bound_scale, "Multiplier of the physical bounds on learned targets (1: base force "
          "m·g, base torque m·g·leg span, joint torques their limits)", "", 0.1, 100.0),
    Param("require_reference", _GATE.require_reference, "Learn only with a /reference at the state's stamp (false: "
          "a log replayed without /reference is learned without the tracking check)"),
    Param("input_timeout", 2.0, "No learning sample this long after the first: WARN on /diagnostics", "s", 0.1,
          3600.0),
    Param("validate_snapshots", True, "Hold samples back and announce a snapshot only where it beats the nominal "
          "model on them (false: learn every sample and announce every snapshot whole, e.g. to compare with an "
          "offline fit of a replayed log; never beside a controller)"),
    Param("hold_back_block", _VALIDATION.block, "Length of a block of stamps; one block in hold_back_every is held "
          "back (not learned) to validate snapshots on", "s", 0.01, 60.0),
    Param("hold_back_every", _VALIDATION.every, "One block of stamps in this many is held back", "", 2, 100),
    Param("validation_window", _VALIDATION.window, "Newest held-back samples a snapshot is validated on", "", 10,
          100000),
    Param("min_learned", _VALIDATION.min_learned, "Samples learned before a snapshot may be served", "", 0, 10**7),
    Param("min_heldout", _VALIDATION.min_heldout, "Held-back samples, per output, for a decision on that output",
          "", 1, 100000),
    Param("validation_margin", _VALIDATION.margin, "A snapshot's output is served only if its mean squared error on "
          "held-back samples is at most (1 − margin) × the nominal model's", "", 0.0, 0.99),
    ROBOT,
))

SCHEMAS: tuple[NodeSchema, ...] = (STATE_FILTER, ERROR_EXTRACTOR, MODEL_SERVER, ONLINE_LEARNER, STATE_PUBLISHER)
