"""`model_server`: /reference + /model_update → /model_error/predicted (mean and variance).

Thin adapter around ciml_learning.learning.serving (load_served_model, predict_at_reference) and
ciml_learning.learning.workers (LatestOnlyWorker). For every /reference (qᵈ, q̇ᵈ, q̈ᵈ, contacts) it
publishes a ciml_msgs/ModelError stamped like the reference: Φ̃' (18) and Γ (n_j) predicted
at the reference's state and the torque it asks for (τ_ref and its rate over the reference
stream, dynamics.ReferenceTorque) with their predictive variances (the set learns Φ̃ = J'ᵀΦ̃'; Φ̃' = J'⁻ᵀΦ̃ with
the basis at qᵈ), `source` = the model's name ("<learner>:<folder name>"), observed = the
entry is backed by learned models.

Nominal model (source "nominal"): zeros, all observed flags false and the prior variance
of serving.nominal_prediction (large: (5 % of the weight-derived force scale)²) — served
when no model is loaded (model_dir '') or when a prediction is non-finite (counted).

The launch's model (model_dir) is loaded and validated before the node answers any reference,
so it serves from the first one. Hot swap without a gap: a /model_update is loaded and
validated on a worker thread (serving.load_served_model: ModelSet.load's checks with the
whole-model checksum; an announcement must carry that checksum; predictions on the model's
own training inputs within the robot's physical bounds); the node swaps its served model
in its own thread between two references, so the old model serves until the new one is
ready. A model swaps in only once the one serving has served `min_serve_time` of reference
stamps (serving.SwapHold), so the controller assesses every model it serves, doubled after
each rollback in a row (swap_hold_ms). Only the newest announcement is loaded, and only
LOAD_AHEAD before the hold ends (the others are counted as model_updates_superseded): a load
costs 0.15–0.5 s of CPU, and loading every 5 s snapshot through a 96 s hold spent it on ~90
models that never served (go1, results/LIVE_GRAPH.md, twentieth session); one announced while a
loaded one waits takes its place (models_superseded).
A refused model (announced without or with another checksum, tampered, truncated, wrong version
or robot, predicting beyond physical bounds, e.g. scaled ×1e6) is logged,
counted (refused_models) and the old model keeps serving. Rejected references
(non-finite, wrong names) are counted and produce no output: NaN never reaches /model_error/predicted.

Rollback: a /model_rollback naming the model being served (the controller's EffortWatch saw
the feedback effort or the base tracking error jump while it served: ciml_learning.learning.rollback)
puts back the model served before it (the last one not rolled back; the nominal model if none),
counted (rollbacks, WARN); a model rolled back is never served again.
"""
from __future__ import annotations

from ciml_msgs.msg import ModelError, ModelUpdate, RobotReference
from rclpy.node import Node
from std_msgs.msg import String

from ciml_learning.core import conversions as cv
from ciml_learning.core import topics
from ciml_learning.core.dynamics import ReferenceState, ReferenceTorque
from ciml_learning.core.errors import CimlError
from ciml_learning.core.profile import load_profile
from ciml_learning.learning.serving import ServedModel, SwapHold, load_served_model, predict_at_reference
from ciml_learning.learning.workers import LatestOnlyWorker
from ciml_learning.ros import realtime
from ciml_learning.ros.node_params import MODEL_SERVER
from ciml_learning.ros.ros_common import COMMAND_QOS, Health, declare_schema, run_node

MAX_PREVIOUS = 3
"""Models kept in memory to roll back to (each ~ the size of a snapshot)."""
LOAD_AHEAD = 2.0
"""[s] of reference stamps before the hold ends at which the newest announced model is loaded
(loads take 0.15–0.5 s of CPU on a 2-core machine beside the graph, up to ~1 s at start)."""


class ModelServerNode(Node):
    def __init__(self, **kwargs) -> None:
        super().__init__("model_server", **kwargs)
        p = declare_schema(self, MODEL_SERVER)  # node_params.py: the one schema (all read-only)
        model_dir, swap_period = p["model_dir"], p["swap_check_period"]
        self.robot = load_profile(p["robot"]).robot()
        self.served: ServedModel | None = None
        self.previous: list[ServedModel] = []   # served before the current one, newest last (rollback)
        self.rolled_back: set[str] = set()
        self.hold = SwapHold(p["min_serve_time"])
        self.loaded: ServedModel | None = None  # validated, waiting for the hold to end
        self.reference_torque = ReferenceTorque(self.robot)  # τ̇_ref of the stream, across model swaps
        self.health = Health(self)
        self.health.set(0, "serving the nominal model")
        self.loader = LatestOnlyWorker(self._load, name="model-loader")
        self.announced: tuple[str, str] | None = None  # the newest /model_update not loaded yet
        self.pub = self.create_publisher(ModelError, topics.MODEL_ERROR_PREDICTED, COMMAND_QOS)
        self.create_subscription(RobotReference, topics.REFERENCE, self.on_reference, COMMAND_QOS)
        self.create_subscription(ModelUpdate, topics.MODEL_UPDATE, self.on_update, COMMAND_QOS)
        self.create_subscription(String, topics.MODEL_ROLLBACK, self.on_rollback, COMMAND_QOS)
        self.create_timer(swap_period, self.swap)
        if model_dir:
            self._serve_initial(model_dir)

    def _serve_initial(self, model_dir: str) -> None:
        """The launch's model serves from the first reference: loaded here, before any prediction
        (not announced: its own checksum is verified). Loaded on the worker, it reached the
        controller ~1 s after the first references, and the controller's rollback judged it
        against those nominal standing seconds: the trot that followed rolled it back (go1,
        results/LIVE_GRAPH.md, twenty-fifth session). A refused one leaves the nominal model."""
        try:
            self.served = load_served_model(self.robot, model_dir)
        except CimlError as err:
            self.health.count("refused_models", f"model {model_dir} refused ({err}); serving the nominal model")
            self.get_logger().error(f"model refused: {err}")
            return
        self.hold.swapped()
        self.health.counts["model_swaps"] += 1
        self.health.set(0, f"serving {self.served.name}")
        self.get_logger().info(f"serving {self.served.model_dir}")

    def _load(self, item: tuple[str, str | None]) -> ServedModel:
        # a load is ~1 s of CPU: it must not take the real-time priority the predictions have
        realtime.normal_scheduling()
        return load_served_model(self.robot, *item)

    def on_update(self, msg) -> None:
        self.health.counts["model_updates"] += 1
        if self.announced is not None:
            self.health.counts["model_updates_superseded"] += 1
        self.announced = (msg.model_dir, msg.checksum)

    def swap(self) -> None:
        """Load the newest announced model once the hold is nearly over; install models loaded by the
        worker (runs in the executor: never during a prediction)."""
        if self.announced is not None and self.hold.remaining_s() <= LOAD_AHEAD and not self.loader.busy:
            self.loader.submit(self.announced)
            self.announced = None
        for result in self.loader.drain():
            model_dir = result.item[0]
            if result.error is not None:
                kept = self.served.name if self.served is not None else "the nominal model"
                self.health.count("refused_models", f"model {model_dir} refused ({result.error}); still serving {kept}")
                self.get_logger().error(f"model refused: {result.error}")
                continue
            if result.value.name in self.rolled_back:
                self.health.count("refused_models", f"model {model_dir} was rolled back: not served again")
                continue
            if self.loaded is not None:
                self.health.counts["models_superseded"] += 1
            self.loaded = result.value
            self.health.counts["load_ms"] = int(round(1e3 * result.seconds))
        if self.loaded is None or not self.hold.may_swap():
            return
        if self.served is not None:
            self.previous = [*self.previous, self.served][-MAX_PREVIOUS:]
        self.served, self.loaded = self.loaded, None
        self.hold.swapped()
        self.health.counts["swap_hold_ms"] = int(round(1e3 * self.hold.hold_s()))
        self.health.counts["model_swaps"] += 1
        self.health.set(0, f"serving {self.served.name}")
        self.get_logger().info(f"serving {self.served.model_dir} (loaded in {self.health.counts['load_ms']} ms)")

    def on_rollback(self, msg) -> None:
        """Stop serving the named model; the one served before it takes over (module docstring)."""
        name = str(msg.data)
        self.rolled_back.add(name)
        self.previous = [m for m in self.previous if m.name not in self.rolled_back]
        if self.served is None or self.served.name != name:
            self.health.counts["rollbacks_not_serving"] += 1  # already replaced: nothing to undo
            return
        self.served = self.previous.pop() if self.previous else None
        self.hold.rolled_back()
        self.health.counts["swap_hold_ms"] = int(round(1e3 * self.hold.hold_s()))
        back = self.served.name if self.served is not None else "the nominal model"
        self.health.count("rollbacks", f"model {name} rolled back by the controller; serving {back}")
        self.health.set(0, f"serving {back}")

    def on_reference(self, msg) -> None:
        try:
            q, v, a, contacts = cv.robot_reference_arrays(self.robot, msg)
        except CimlError as err:
            self.health.count("rejected_references", f"reference rejected: {err}")
            return
        stamp = cv.stamp_to_ns(msg.header.stamp)
        self.hold.reference(stamp)
        ref = ReferenceState(stamp * 1e-9, q, v, a, contacts)
        pred = predict_at_reference(self.robot, self.served, ref, self.reference_torque)
        if pred.fallback == "no_model":
            self.health.counts["nominal_no_model"] += 1
        elif pred.fallback is not None:
            self.health.count(pred.fallback, f"{pred.fallback}: serving the nominal model")
        self.pub.publish(cv.model_error_msg(self.robot, stamp, pred.source, pred.rbd_error,
                                            pred.rbd_observed, pred.actuation_error, pred.actuation_observed,
                                            pred.rbd_variance, pred.actuation_variance, pred.generalized_variance))
        self.health.counts["predictions"] += 1

    def destroy_node(self) -> None:
        self.loader.close(timeout=5.0)
        super().destroy_node()


def main(args=None) -> None:
    run_node(ModelServerNode, args)
