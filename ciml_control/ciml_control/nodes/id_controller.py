"""`id_controller`: inverse-dynamics QP controller on the live graph (docs/ARCHITECTURE.md §3).

Thin adapter around ciml_control.controller.IdController. Each /joint_states sample
(250 Hz from the robot) triggers one control step with the latest base state, contact
state, reference and model-error prediction; the command is stamped with that joint
sample's stamp. A watchdog timer at `rate` commands damping when the state stops.

Standing start (docs/LIVE_GRAPH.md): until its inputs (joint, base and contact state and
/reference) are fresh for the first time the node publishes nothing ("not ready yet",
/diagnostics WARN "waiting for …"), so the robot driver keeps its own safe state (the
bridge holds the robot standing until the first MODE_TORQUE command).

Safety once it has commanded torque (counted on /diagnostics):
- joint, base or contact state missing or older than `state_timeout` (time since
  receipt, on the node clock: run with use_sim_time:=true next to a simulator, so that
  a stalled simulation does not look like a dead robot), or /reference older than
  `reference_hold` → TorqueCommand MODE_DAMPING (no torque, no stiffness, joint damping only);
- /reference older than `reference_timeout` but not `reference_hold`: safe stop
  (ciml_control.safe_stop; counted: reference_held, with a warning): the base and stance feet
  hold the last reference, the swing feet land within `landing_time`, then the robot stands.
  A reference node that stalls for a few hundred milliseconds (measured in the live graph)
  must not drop the robot, and holding a trot's pose did (two feet in the air, then a
  reference that came back ahead of the stopped robot). A fresh reference is tracked again
  only within `resume_tolerance` of the stop's base; otherwise the robot keeps standing on it
  (counted: reference_not_resumed, with a warning) until the motion restarts. With
  `wait_for_reference` (a simulator in lockstep: the launch file's `lockstep`) the joint sample
  is answered only when a fresh reference arrives, one stamped at most `max_reference_lag`
  before the sample (counted: reference_waits): the simulation waits for a stalled reference
  node as it waits for this one, and a reference held and then caught up cannot leap ahead;
- non-finite or mismatched inputs are dropped by the conversions (never used);
- a controller error (ControllerInputError) → damping for that step;
- QP failures → the controller's documented fallback; counted.
Reference and model error by stamp: a step tracks the /reference stamped like its joint sample
(the reference_generator publishes ahead: `lookahead`), else the newest (counted:
reference_lag_mean_ms / _p50_ms / _p99_ms, the sample's stamp minus its reference's), and uses the
/model_error/predicted made for that reference, else the nearest within `max_prediction_lag` (a
model server that falls behind answers for another instant of the gait), if the newest is
younger than `model_error_timeout` (counted: prediction_behind_reference, prediction_lag_mean_ms /
_p50_ms / _p99_ms) gives ε = J'ᵀ Φ̃' − Sᵀ Γ
(eq. 17) with the contact-invariant basis at the reference configuration; otherwise ε = 0
(nominal model: a model server that is late, restarted or absent never stops the controller).
All predicted entries pass the trust law
(ciml_control.trust, the same as the headless closed loop's): an entry whose predictive
variance exceeds `max_variance_ratio` × its prior variance is not used (counted:
epsilon_gated, steps with a gated entry) — the entries of Φ̃ = J'ᵀΦ̃' and Γ, the coordinates
the model predicted in, when the prediction carries Φ̃'s variance (else those of Φ̃') — and ε
is clipped to the robot's physical bounds (m·g, m·g·leg span, torque limits; counted:
epsilon_clipped, with a warning).
Outputs for a robot's own controllers: with `effort_command_topic` every command (damping too) is
also published as ros2_control takes it — a std_msgs/Float64MultiArray of the joint-loop law's
torque at the command's sample (conversions.commanded_torque, clipped to the limits; a
forward_command_controller holds it until the next one, there is no 1 kHz PD between), in the
profile's joint order (conversions.effort_joint_order). With `feedforward_only` the node commands
nothing: per joint sample it solves the QP with ε and with ε = 0 and publishes the difference of
the two feedforwards, the learned correction in joint torques, on /model_error/feedforward
(sensor_msgs/JointState: names, effort [Nm], the joint sample's stamp; zero while no model is
served or trusted; not published after a QP failure, counted feedforward_skipped).
Rollback (`rollback`): every step's feedback effort and base position error go to an
EffortWatch (ciml_learning.learning.rollback) with the `source` of the prediction used; when a newly
served model makes either rise beyond `rollback_rise` × the RMS of the seconds before it (RMS
over `rollback_window`, during `rollback_probation`), or its RMS effort over its first
`rollback_assess` seconds exceeds that of the seconds before it by more than `rollback_worse`
(a model that passed is not judged again when a rollback puts it back),
its predictions are no longer used (ε = 0) and /model_rollback asks the model server to serve
the model before it (counted: rollbacks, rollbacks_worse_than_before, rollback_detect_ms, with a
warning). models_judged / models_unjudged: the new models the watch assessed or rolled back, and
those it could not judge (no reference before them, or replaced before their assessment).
"""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from typing import Any, TypeGuard, TypeVar

import numpy as np
from ciml_msgs.msg import ContactState, ModelError, RobotReference, TorqueCommand
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.errors import CimlError
from ciml_learning.core.pairing import ReferenceHistory
from ciml_learning.core.profile import load_profile
from ciml_learning.core.projection import contact_invariant_basis
from ciml_learning.learning.rollback import (
    NOMINAL_SOURCE,
    WORSE_THAN_BEFORE,
    EffortWatch,
    RollbackConfig,
    feedback_effort,
    margins_for,
)
from ciml_learning.ros.ros_common import (
    COMMAND_QOS,
    LATEST_QOS,
    OK,
    WARN,
    Health,
    PublishPeriods,
    declare_schema,
    run_node,
)

from ..controller import ControlOutput, IdController
from ..conversions import effort_array_msg, effort_joint_order, feedforward_msg, reference_point
from ..feedback import FeedbackGains
from ..node_params import ID_CONTROLLER
from ..references import ReferencePoint, make_reference, standing_configuration
from ..safe_stop import LIVE, SafeStop
from ..standing import safe_damping_gain
from ..trust import TrustLaw

MODE_TORQUE = 0
MODE_DAMPING = 1

HISTORY = 16
"""References and predictions kept by stamp (64 ms at 250 Hz)."""

STATE_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)
"""State topics: only the newest sample matters to a controller (a backlog only adds latency)."""

T = TypeVar("T")
Stamped = tuple[float, int, T]
"""An input as the node keeps it: (receipt time on the node clock [s], header stamp [ns], converted message)."""


class IdControllerNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("id_controller", **kwargs)
        p = declare_schema(self, ID_CONTROLLER, self._apply_parameters)  # node_params.py: the one schema
        self.params = dict(p)
        rate, ratio = p["rate"], p["max_variance_ratio"]
        self.state_timeout, self.reference_timeout = p["state_timeout"], p["reference_timeout"]
        self.reference_hold = p["reference_hold"]
        self.model_error_timeout, self.use_model_error = p["model_error_timeout"], p["use_model_error"]
        profile = load_profile(p["robot"])
        self.robot = profile.robot()
        self.watch = EffortWatch(RollbackConfig(window=p["rollback_window"], probation=p["rollback_probation"],
                                                rise=p["rollback_rise"], assess=p["rollback_assess"],
                                                worse=p["rollback_worse"],
                                                margins=margins_for(self.robot.torque_limits)))
        self.feedforward_only = p["feedforward_only"]
        self.effort_order = effort_joint_order(profile, self.robot)  # the array's order: checked at start
        self.damping_gain = p["damping_gain"] or safe_damping_gain(self.robot)  # 0: derived from the robot's size
        self.trust = TrustLaw(self.robot, ratio)
        self.commanding = False  # a MODE_TORQUE command has been published (then stale inputs → damping)
        self._damped = False     # the last command was MODE_DAMPING
        self._awaiting_reference = False  # the newest joint sample waits for a fresh /reference
        self.controller = self._build_controller(p)
        self.q_stand = standing_configuration(self.robot, 0.002)
        self.safe_stop = SafeStop(self.robot, self.q_stand, p["landing_time"], p["resume_tolerance"])
        self._warm_up()
        self.health = Health(self)
        self.periods = PublishPeriods(self.health, "torque_command", rate)  # commands as published
        self.joints: Stamped[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None  # (q, qd, tau)
        self.base: Stamped[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None  # (position, quaternion, twist)
        self.contacts: Stamped[np.ndarray] | None = None
        self.reference: Stamped[ReferencePoint] | None = None      # the newest (freshness)
        self.model_error: Stamped[cv.ModelErrorArrays] | None = None  # the newest (freshness)
        # by stamp: a step takes the reference of its joint sample's instant and that reference's
        # prediction, which a reference published ahead (reference_generator's lookahead) provides
        self.references = ReferenceHistory(0, HISTORY)
        self.predictions = ReferenceHistory(0, HISTORY)
        self._set_lags(self.params)
        self.compute_times: deque = deque(maxlen=1000)
        self.prediction_lags: deque = deque(maxlen=1000)  # |reference stamp − its prediction's| [s]
        self.reference_lags: deque = deque(maxlen=1000)   # joint sample stamp − its reference's [s]
        self.pub = self.create_publisher(TorqueCommand, topics.TORQUE_COMMAND, COMMAND_QOS)
        self.effort_pub = (self.create_publisher(Float64MultiArray, p["effort_command_topic"], COMMAND_QOS)
                           if p["effort_command_topic"] else None)
        self.feedforward_pub = (self.create_publisher(JointState, topics.MODEL_ERROR_FEEDFORWARD, COMMAND_QOS)
                                if self.feedforward_only else None)
        self.rollback_pub = self.create_publisher(String, topics.MODEL_ROLLBACK, COMMAND_QOS)
        # base and contacts first: rclpy's executor takes ready subscriptions in creation order, and
        # the robot driver publishes a sample's base and contact state before its joint state (the
        # trigger), so the control step sees the whole sample, not the previous base state
        self.create_subscription(Odometry, topics.BASE_STATE, self.on_base, STATE_QOS)
        self.create_subscription(ContactState, topics.CONTACT_STATE, self.on_contacts, STATE_QOS)
        self.create_subscription(JointState, topics.JOINT_STATES, self.on_joints, STATE_QOS)
        self.create_subscription(RobotReference, topics.REFERENCE, self.on_reference, LATEST_QOS)
        self.create_subscription(ModelError, topics.MODEL_ERROR_PREDICTED, self.on_model_error, LATEST_QOS)
        self.create_timer(1.0 / rate, self.watchdog)
        self.create_timer(1.0, self.report)

    def _build_controller(self, p: dict) -> IdController:
        # kp, kd 0: derived from the robot's size (feedback.joint_gain_scale)
        gains = FeedbackGains.default(self.robot, p["kp"] or None, p["kd"] or None,
                                      (p["base_kp_linear"], p["base_kp_angular"]),
                                      (p["base_kd_linear"], p["base_kd_angular"]), p["joint_lin_kp"],
                                      p["joint_lin_kd"])
        return IdController(self.robot, gains, mu=p["mu"], f_min=p["f_min"], feedback_contacts=p["feedback_contacts"])

    CONTROLLER_PARAMETERS = frozenset({"kp", "kd", "base_kp_linear", "base_kp_angular", "base_kd_linear",
                                       "base_kd_angular", "joint_lin_kp", "joint_lin_kd", "mu", "f_min",
                                       "feedback_contacts"})

    def _set_lags(self, params: dict) -> None:
        """The largest stamp distances of a step's reference and prediction (`max_reference_lag`,
        `max_prediction_lag`)."""
        self.references.max_age_ns = int(params["max_reference_lag"] * 1e9)
        self.predictions.max_age_ns = int(params["max_prediction_lag"] * 1e9)

    def _apply_parameters(self, changes: dict) -> str | None:
        """Run-time sets: timeouts and switches at the next tick; gains, cone and contact set by
        rebuilding the controller (~20 ms, between two ticks of this single-threaded node)."""
        params = {**self.params, **changes}
        if self.CONTROLLER_PARAMETERS & changes.keys():
            try:
                controller = self._build_controller(params)
            except (CimlError, ValueError) as err:
                return f"controller not rebuilt: {err}"
            self.controller = controller
        if "max_variance_ratio" in changes:
            self.trust = TrustLaw(self.robot, changes["max_variance_ratio"])
        self.params = params
        self._set_lags(params)
        self.state_timeout, self.reference_timeout = params["state_timeout"], params["reference_timeout"]
        self.reference_hold = params["reference_hold"]
        self.model_error_timeout, self.use_model_error = params["model_error_timeout"], params["use_model_error"]
        self.damping_gain = params["damping_gain"] or safe_damping_gain(self.robot)
        return None

    def _warm_up(self) -> None:
        """One control step at the standing reference before any input: the first step loads the
        compiled core and fills caches (~0.2 s here), which must not delay the first command
        after the robot driver's standing hold (a late first command drops the robot)."""
        ref = make_reference(self.robot, "stand", self.q_stand).sample(0.0)
        t0 = time.perf_counter()
        self.controller.compute(ref.q, ref.v, ref.contacts, ref, np.zeros(self.robot.nv))
        basis = contact_invariant_basis(self.controller.desired_terms(ref)[2], self.robot.leg_joints)
        self.trust.apply(np.zeros(len(self.robot.rbd_error_names)), None, np.zeros(self.robot.n_joints), None, basis)
        self.controller.steps = 0
        self.get_logger().info(f"controller warmed up in {1e3 * (time.perf_counter() - t0):.0f} ms")

    # --- inputs ------------------------------------------------------------------------
    def _convert(self, what: str, fn: Callable[[Any], T], msg: Any) -> Stamped[T] | None:
        try:
            return self._now(), cv.stamp_to_ns(msg.header.stamp), fn(msg)
        except CimlError as err:
            self.health.count(f"rejected_{what}", f"{what} rejected: {err}")
            return None

    def on_base(self, msg: Odometry) -> None:
        self.base = self._convert("base_state", cv.odometry_arrays, msg) or self.base

    def on_contacts(self, msg: ContactState) -> None:
        self.contacts = (self._convert("contact_state", lambda m: cv.contact_state_arrays(self.robot, m), msg)
                         or self.contacts)

    def on_reference(self, msg: RobotReference) -> None:
        reference = self._convert("reference", lambda m: reference_point(self.robot, m), msg)
        if reference is not None:
            self.reference = reference
            self.references.add(reference[1], reference)
        if self._awaiting_reference:  # the joint sample that waited for it (wait_for_reference)
            self._awaiting_reference = False
            self.control()

    def on_model_error(self, msg: ModelError) -> None:
        model_error = self._convert("model_error", lambda m: cv.model_error_arrays(self.robot, m), msg)
        if model_error is not None:
            self.model_error = model_error
            self.predictions.add(model_error[1], model_error)

    def on_joints(self, msg: JointState) -> None:
        joints = self._convert("joint_states", lambda m: cv.joint_state_arrays(self.robot, m), msg)
        if joints is None:
            return
        self.joints = joints
        self.control()

    # --- control -----------------------------------------------------------------------
    def _now(self) -> float:
        """Node clock [s] (simulation time with use_sim_time)."""
        return self.get_clock().now().nanoseconds * 1e-9

    def _fresh(self, item: Stamped[T] | None, timeout: float, now: float) -> TypeGuard[Stamped[T]]:
        return item is not None and now - item[0] <= timeout

    def watchdog(self) -> None:
        now = self._now()
        if not self.commanding:
            self._waiting(now)
        elif not self._fresh(self.joints, self.state_timeout, now):
            self.publish_damping("stale_state", "no fresh joint state: damping")

    def _waiting(self, now: float) -> None:
        """Not ready yet: publish nothing, say what is missing."""
        missing = [name for name, item, timeout in (
            (topics.JOINT_STATES, self.joints, self.state_timeout), (topics.BASE_STATE, self.base, self.state_timeout),
            (topics.CONTACT_STATE, self.contacts, self.state_timeout),
            (topics.REFERENCE, self.reference, self.reference_timeout))
            if not self._fresh(item, timeout, now)]
        self.health.set(WARN, f"waiting for {', '.join(missing) or 'inputs'} before the first command")

    def epsilon(self, ref: ReferencePoint, ref_stamp: int, now: float) -> tuple[np.ndarray, str]:
        """(ε, the source of the prediction it comes from: NOMINAL_SOURCE for ε = 0) at the reference
        stamped ref_stamp [ns]: the prediction made for it, else the nearest one."""
        if not self.use_model_error or not self._fresh(self.model_error, self.model_error_timeout, now):
            return np.zeros(self.robot.nv), NOMINAL_SOURCE
        # a prediction made for another instant of the gait is the wrong correction for this one
        found = self.predictions.at(ref_stamp)
        self.prediction_lags.append(abs(ref_stamp - (found or self.model_error)[1]) * 1e-9)
        if found is None:
            self.health.counts["prediction_behind_reference"] += 1
            return np.zeros(self.robot.nv), NOMINAL_SOURCE
        prediction: cv.ModelErrorArrays = found[2]
        source = prediction.source
        if source in self.watch.rolled_back:  # until the model server has put the model before it back
            self.health.counts["rolled_back_predictions_ignored"] += 1
            return np.zeros(self.robot.nv), NOMINAL_SOURCE
        # the foot Jacobians at qᵈ come from the controller's own Pinocchio pass at the reference
        basis = contact_invariant_basis(self.controller.desired_terms(ref)[2], self.robot.leg_joints)
        self.health.counts["model_error_used"] += 1
        if prediction.generalized_variance is not None:
            # gated in the coordinates the model predicted, Φ̃ = J'ᵀΦ̃' (the headless loop's law): the
            # variance mapped to Φ̃' has lost the covariances and hid go1's uncertain base pitch torque
            trusted = self.trust.apply(basis.T @ prediction.rbd_error, prediction.generalized_variance,
                                       prediction.actuation_error, prediction.actuation_variance)
        else:  # a model server that does not send Φ̃'s variance
            trusted = self.trust.apply(prediction.rbd_error, prediction.rbd_variance, prediction.actuation_error,
                                       prediction.actuation_variance, basis)
        if trusted.gated.any():
            self.health.counts["epsilon_gated"] += 1
        if trusted.clipped.any():
            self.health.count("epsilon_clipped", "model error beyond the robot's physical bounds: clipped")
        return trusted.epsilon, source

    def control(self) -> None:
        now = self._now()
        joints, base, contacts, reference = self.joints, self.base, self.contacts, self.reference
        assert joints is not None  # a step answers a joint sample (on_joints, or the one awaiting /reference)
        stamp = joints[1]
        states_fresh = all(self._fresh(x, self.state_timeout, now) for x in (joints, base, contacts))
        if not self.commanding and not (states_fresh and self._fresh(reference, self.reference_timeout, now)):
            self._waiting(now)  # not ready yet is not stale after running: no command at all
            return
        if not states_fresh:
            self.publish_damping("stale_state", "base or contact state missing or stale: damping", stamp)
            return
        fresh = self._fresh(reference, self.reference_timeout, now)
        wait = self.params["wait_for_reference"]
        # in lockstep a reference for an instant well behind the robot's is late too: held for
        # reference_timeout and then caught up, it leapt ahead of the robot and stopped it for good
        behind = wait and reference is not None and stamp - reference[1] > self.params["max_reference_lag"] * 1e9
        if not fresh or behind:
            if not self._fresh(reference, self.reference_hold, now):
                self.publish_damping("stale_reference", f"no fresh {topics.REFERENCE}: damping", stamp)
                return
            if wait:
                # in lockstep the simulation waits for this answer: wait for the reference instead
                self._awaiting_reference = True
                self.health.counts["reference_waits"] += 1
                return
        assert base is not None and contacts is not None and reference is not None  # fresh or held: received
        reference = self.references.at(stamp) or reference  # the sample's own instant, when published ahead
        self.reference_lags.append((stamp - reference[1]) * 1e-9)
        # a late reference (its node stalled, or restarts) is not a dead one: safe stop, not a fall
        ref, stop = self.safe_stop.track(reference[2], fresh, stamp * 1e-9)  # the robot's sample time
        if stop != LIVE:
            if fresh:
                self.health.count("reference_not_resumed", f"{topics.REFERENCE} came back {self.safe_stop.jump:.3f} m "
                                  "from where the robot stopped: standing until the motion restarts")
            else:
                self.health.count("reference_held", f"no fresh {topics.REFERENCE}: feet down, standing")
        t0 = time.perf_counter()
        qj, qdj, _ = joints[2]
        pos, quat, twist = base[2]
        q = np.concatenate([pos, quat, qj])
        v = np.concatenate([twist, qdj])
        epsilon, source = self.epsilon(ref, reference[1], now)
        try:
            out = self.controller.compute(q, v, contacts[2], ref, epsilon)
        except CimlError as err:
            self.publish_damping("controller_errors", f"controller error: {err}", stamp)
            return
        if out.qp_failed:
            self.health.count("qp_failures", f"QP failed, fallback feedforward: {out.qp_error}")
        if out.epsilon_rejected:
            self.health.count("epsilon_rejected", "non-finite model error: nominal model used")
        if self.feedforward_only:
            self.publish_feedforward(stamp, q, v, contacts[2], ref, out)
            self.compute_times.append(time.perf_counter() - t0)
            return
        cmd = cv.TorqueCommandArrays(mode=MODE_TORQUE, feedforward=out.feedforward,
                                     feedback_linearization=out.feedback_linearization,
                                     position_target=out.q_target, velocity_target=out.qd_target,
                                     stiffness=out.kp, damping=out.kd)
        self.send(stamp, cmd)
        self.periods.mark()
        self.health.counts["commands"] += 1
        if self.params["rollback"]:
            self._watch(now, source, cmd, qj, qdj, q, ref.q)
        if not self.commanding or self._damped:
            self.commanding, self._damped = True, False
            self.health.set(OK, "torque control")
        self.compute_times.append(time.perf_counter() - t0)

    def _watch(self, now: float, source: str, cmd, qj, qdj, q, q_ref) -> None:
        if self.model_error is None:
            # no prediction heard yet (the model server not yet discovered at start): these steps are
            # no reference for a model, and the one launched with the graph then came ~2.5 s late and
            # was judged against the nominal standing start (go1: rolled back as 25 % worse)
            return
        effort = feedback_effort(cmd.stiffness, cmd.damping, cmd.position_target, cmd.velocity_target,
                                 cmd.feedback_linearization, qj, qdj)
        back = self.watch.update(now, source, (effort, EffortWatch.base_position_error(q, q_ref)))
        counts = self.health.counts
        counts["models_judged"], counts["models_unjudged"] = self.watch.judged, self.watch.unjudged
        if back is None:
            return
        self.rollback_pub.publish(String(data=back.source))
        self.health.counts["rollback_detect_ms"] = int(round(1e3 * back.detected_after))
        if back.kind == WORSE_THAN_BEFORE:
            self.health.counts["rollbacks_worse_than_before"] += 1
        self.health.count("rollbacks", f"model {back.source} rolled back ({back.kind.replace('_', ' ')}): "
                                       f"{back.signal} RMS {back.rms:.3g} above {back.limit:.3g} "
                                       f"{1e3 * back.detected_after:.0f} ms after it served")

    def send(self, stamp: int, cmd: cv.TorqueCommandArrays) -> None:
        """A command to the robot: /torque_command, and the ros2_control effort array if asked."""
        self.pub.publish(cv.torque_command_msg(self.robot, stamp, cmd))
        if self.effort_pub is not None:
            qj, qdj = self.joints[2][:2] if self.joints is not None else (cmd.position_target, cmd.velocity_target)
            u = cmd.total(qj, qdj, self.robot.torque_limits)  # the joint-loop law at this sample, within the limits
            self.effort_pub.publish(effort_array_msg(u, self.effort_order))

    def publish_feedforward(self, stamp: int, q: np.ndarray, v: np.ndarray, contacts: np.ndarray, ref: ReferencePoint,
                            out: ControlOutput) -> None:
        """feedforward_only: the QP feedforward with the trusted ε minus the nominal model's."""
        assert self.feedforward_pub is not None  # created with feedforward_only, the only case that calls this
        nominal = self.controller.compute(q, v, contacts, ref, np.zeros(self.robot.nv))
        if out.qp_failed or nominal.qp_failed:  # a fallback torque is no learned correction
            self.health.count("feedforward_skipped", "QP failed: no learned feedforward for this sample")
            return
        self.feedforward_pub.publish(feedforward_msg(self.robot, stamp, out.feedforward - nominal.feedforward))
        self.health.counts["feedforwards"] += 1
        if self.health.mode_message != "feedforward only":
            self.health.set(OK, "feedforward only")

    def publish_damping(self, event: str, reason: str, stamp: int | None = None) -> None:
        n = self.robot.n_joints
        q_now = self.joints[2][0] if self.joints is not None else np.zeros(n)
        cmd = cv.TorqueCommandArrays(mode=MODE_DAMPING, feedforward=np.zeros(n), feedback_linearization=np.zeros(n),
                                     position_target=q_now, velocity_target=np.zeros(n), stiffness=np.zeros(n),
                                     damping=np.full(n, self.damping_gain))
        self.send(stamp if stamp is not None else self.get_clock().now().nanoseconds, cmd)
        self.health.count(event, reason)
        if not self._damped:
            self._damped = True
            self.health.set(WARN, reason)

    def report(self) -> None:
        if self.compute_times:
            t = np.array(self.compute_times) * 1e6
            self.health.counts["compute_p50_us"] = int(np.percentile(t, 50))
            self.health.counts["compute_p99_us"] = int(np.percentile(t, 99))
        for name, lags in (("prediction", self.prediction_lags), ("reference", self.reference_lags)):
            if lags:
                lag = np.array(lags) * 1e3
                self.health.counts[f"{name}_lag_mean_ms"] = round(float(np.mean(lag)), 2)
                self.health.counts[f"{name}_lag_p50_ms"] = round(float(np.percentile(lag, 50)), 1)
                self.health.counts[f"{name}_lag_p99_ms"] = round(float(np.percentile(lag, 99)), 1)


def main(args: list[str] | None = None) -> None:
    import sys

    try:
        run_node(IdControllerNode, args)
    except CimlError as err:
        print(f"id_controller: {err}", file=sys.stderr)
        sys.exit(1)
