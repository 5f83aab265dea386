"""reference_generator and id_controller on the live graph (DDS on loopback)."""
from __future__ import annotations

import time

import numpy as np
import pytest
from rosutil import Listener, start_node, stop

from ciml_control.conversions import reference_msg, reference_point
from ciml_control.node_params import ID_CONTROLLER
from ciml_control.references import make_reference, standing_configuration
from ciml_learning.core import conversions as cv
from ciml_learning.core.robot import load_robot

ROBOT = load_robot()


@pytest.mark.ros
def test_reference_generator_stands_until_torque_control_then_runs_the_motion():
    from ciml_msgs.msg import RobotReference, TorqueCommand

    listener = Listener({"/reference": RobotReference})
    refs = listener.messages["/reference"]
    command = listener.node.create_publisher(TorqueCommand, "/torque_command", 10)
    node = start_node("reference_generator", "-p", "motion:=trot_35", "-p", "start_delay:=0.5")
    q_stand = standing_configuration(ROBOT, 0.002)
    n = ROBOT.n_joints
    try:
        # subscribers alone (this listener) do not start the motion, nor does a damping command
        assert listener.wait_for(lambda: len(refs) >= 250 and command.get_subscription_count() >= 1,
                                 timeout=30), stop(node)
        command.publish(cv.torque_command_msg(ROBOT, 0, cv.TorqueCommandArrays(
            1, np.zeros(n), np.zeros(n), q_stand[7:], np.zeros(n), np.zeros(n), np.full(n, 10.0))))
        time.sleep(0.3)
        standing = len(refs)
        # the robot comes under torque control: the motion starts start_delay later
        command.publish(cv.torque_command_msg(ROBOT, 0, cv.TorqueCommandArrays(
            0, np.zeros(n), np.zeros(n), q_stand[7:], np.zeros(n), np.full(n, 300.0), np.full(n, 8.0))))
        ok = listener.wait_for(lambda: len(refs) >= standing + 500, timeout=30)
    finally:
        log = stop(node)
        listener.close()
    assert ok, log
    points = [reference_point(ROBOT, m) for m in refs]
    assert all(p.motion == "trot_35" for p in points)
    assert all(np.allclose(p.q, q_stand, atol=1e-3) for p in points[:standing])
    stamps = np.array([p.t for p in points])
    assert np.all(np.diff(stamps) > 0)
    rate = (len(stamps) - 1) / (stamps[-1] - stamps[0])
    assert 150 < rate < 300  # 250 Hz nominal on a shared machine
    # the first sample off the standing pose comes ≥ start_delay after the torque command
    moving = next(k for k, p in enumerate(points) if not np.allclose(p.q, q_stand, atol=1e-6))
    assert moving > standing and stamps[moving] - stamps[standing - 1] >= 0.5 - 0.02
    # the samples are the motion's reference at its phase in some gait cycle k
    ref = make_reference(ROBOT, "trot_35", q_stand)
    p = points[-1]
    cycles = int((p.t - points[moving].t - ref.t0) / ref.period) + 2
    matches = [k for k in range(max(cycles, 1))
               if np.allclose(p.q, (e := ref.sample(ref.t0 + (k + p.phase) * ref.period)).q, atol=1e-6)
               and np.array_equal(p.contacts, e.contacts)]
    assert matches, "the last reference sample is not the motion's reference at its phase"


@pytest.mark.ros
def test_the_reference_is_published_ahead_and_the_controller_takes_its_samples_instant():
    """reference_generator stamps each /reference `lookahead` ahead of its clock with the motion
    sampled at that instant; id_controller, given references and predictions of several instants,
    steps a joint sample on the reference stamped like it and that reference's own prediction
    (lag 0), not the newest of each (one period ahead here)."""
    import rclpy

    from ciml_control.nodes.id_controller import IdControllerNode
    from ciml_control.nodes.reference_generator import ReferenceGeneratorNode

    node, ctx = _in_process(ReferenceGeneratorNode, motion="trot_35", start_on_command=False, start_delay=0.0,
                            lookahead=0.004)
    try:
        out: list = []
        node.pub.publish = out.append
        before = node.get_clock().now().nanoseconds
        node.tick()
        after = node.get_clock().now().nanoseconds
        stamp = cv.stamp_to_ns(out[0].header.stamp)
        assert before + 4_000_000 <= stamp <= after + 4_000_000
        expected = make_reference(ROBOT, "trot_35", standing_configuration(ROBOT, 0.002)).sample(
            (stamp - node.start_ns) * 1e-9)
        assert np.allclose(reference_point(ROBOT, out[0]).q, expected.q, atol=1e-9)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
    node, ctx = _in_process(IdControllerNode)
    try:
        node.pub.publish = lambda msg: None
        ns = 10**9
        q_stand = standing_configuration(ROBOT, 0.002)
        ref = make_reference(ROBOT, "stand", q_stand).sample(0.0)
        zeros = np.zeros(ROBOT.n_joints)
        for k in (0, 1):  # the sample's instant and one period ahead
            node.on_reference(reference_msg(ROBOT, ns + 4_000_000 * k, ref))
            node.on_model_error(cv.model_error_msg(ROBOT, ns + 4_000_000 * k, "test", np.zeros(18),
                                                   np.zeros(18, bool), zeros, np.zeros(ROBOT.n_joints, bool)))
        node.on_base(cv.odometry_msg(ns, q_stand[:3], q_stand[3:7], np.zeros(3), np.zeros(3)))
        node.on_contacts(cv.contact_state_msg(ROBOT, ns, np.ones(ROBOT.n_feet, bool)))
        node.on_joints(cv.joint_state_msg(ROBOT, ns, q_stand[7:], zeros, zeros))
        assert node.reference[1] == ns + 4_000_000  # the newest is ahead …
        assert node.reference_lags[-1] == 0.0        # … the step took the sample's own
        assert node.prediction_lags[-1] == 0.0       # and the prediction made for it
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_steps_before_any_prediction_are_no_reference_for_the_first_model():
    """Until the first /model_error/predicted arrives (the model server not yet discovered at start)
    the rollback watch is not fed: the model launched with the graph, whose predictions come
    seconds after the first command, is not judged against that standing start."""
    import rclpy

    from ciml_control.nodes.id_controller import IdControllerNode

    node, ctx = _in_process(IdControllerNode)
    try:
        node.pub.publish = lambda msg: None
        ns = 10**9
        for k in range(800):  # 3.2 s of standing steps without a prediction (> half the 5 s baseline)
            _feed_standing(node, ROBOT, ns + 4_000_000 * k)
        zeros = np.zeros(ROBOT.n_joints)
        k = 800
        prediction = cv.model_error_msg(ROBOT, ns + 4_000_000 * k, "lwpr:launched", np.zeros(18),
                                        np.zeros(18, bool), zeros, np.zeros(ROBOT.n_joints, bool))
        _feed_standing(node, ROBOT, ns + 4_000_000 * k, model_error=prediction)
        assert node.watch.current == "lwpr:launched"
        assert node.watch.unjudged == 1 and node.watch._pending is False  # no baseline: not judged
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_id_controller_waits_then_commands_limited_trusted_torque_and_damps_without_state():
    from ciml_msgs.msg import ContactState, ModelError, RobotReference, TorqueCommand
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    listener = Listener({"/torque_command": TorqueCommand, "/diagnostics": DiagnosticArray})
    pubs = {
        "/reference": listener.node.create_publisher(RobotReference, "/reference", 10),
        "/joint_states": listener.node.create_publisher(JointState, "/joint_states", 10),
        "/base_state": listener.node.create_publisher(Odometry, "/base_state", 10),
        "/contact_state": listener.node.create_publisher(ContactState, "/contact_state", 10),
        "/model_error/predicted": listener.node.create_publisher(ModelError, "/model_error/predicted", 10),
    }
    node = start_node("id_controller")
    cmds = listener.messages["/torque_command"]
    q_stand = standing_configuration(ROBOT, 0.002)
    ref = make_reference(ROBOT, "stand", q_stand).sample(0.0)
    try:
        # no input yet: "not ready" is not "stale after running" → no command at all (the robot
        # driver keeps its own safe state), and /diagnostics says what it waits for
        assert listener.wait_for(lambda: listener.node.count_publishers("/torque_command") >= 1
                                 and all(p.get_subscription_count() >= 1 for p in pubs.values())
                                 and any("id_controller" in s.name for d in listener.messages["/diagnostics"]
                                         for s in d.status), timeout=30), stop(node)
        time.sleep(1.5)
        assert cmds == []
        waiting = [s for d in listener.messages["/diagnostics"] for s in d.status if "id_controller" in s.name]
        last = waiting[-1]
        assert last.level == b"\x01" and "waiting for" in last.message and "/reference" in last.message
        # a static standing state at 250 Hz → torque commands
        n_before = len(cmds)
        rng = np.random.default_rng(0)
        phi = np.zeros(18)
        phi[2] = 60.0  # the model says: 60 N more weight on the base
        gamma = np.full(ROBOT.n_joints, -2.0)  # and every actuator delivers 2 Nm too little
        huge = np.zeros(18)
        huge[2] = 1e6   # a poisoned prediction: 1e6 N on the base
        ones_r, ones_a = np.ones(18, bool), np.ones(ROBOT.n_joints, bool)
        phases = {}     # joint-state stamp → the prediction's phase
        for k in range(700):
            ns = time.time_ns()
            phases[ns] = "nominal"
            if 250 <= k < 375:  # confident prediction (variance 0): used
                phases[ns] = "confident"
                pubs["/model_error/predicted"].publish(
                    cv.model_error_msg(ROBOT, ns, "test", phi, ones_r, gamma, ones_a))
            elif 375 <= k < 475:  # the same mean, but the model is less certain than the prior: gated
                phases[ns] = "uncertain"
                pubs["/model_error/predicted"].publish(cv.model_error_msg(
                    ROBOT, ns, "test", phi, ones_r, gamma, ones_a, np.full(18, 1e8), np.full(ROBOT.n_joints, 1e6)))
            elif k >= 600:  # the model server stops (restart, crash): the nominal model, never damping
                phases[ns] = "server_gone"
            elif k >= 475:  # confident but beyond the robot's physics: clipped to m·g
                phases[ns] = "huge"
                pubs["/model_error/predicted"].publish(cv.model_error_msg(ROBOT, ns, "test", huge, ones_r,
                                                                          np.zeros(ROBOT.n_joints), ones_a))
            qj = q_stand[7:] + 0.01 * rng.standard_normal(ROBOT.n_joints)
            pubs["/reference"].publish(reference_msg(ROBOT, ns, ref))
            pubs["/base_state"].publish(cv.odometry_msg(ns, q_stand[:3], q_stand[3:7], np.zeros(3), np.zeros(3)))
            pubs["/contact_state"].publish(cv.contact_state_msg(ROBOT, ns, np.ones(4, bool)))
            if k in (100, 150, 200):  # a non-finite sample is dropped, never used (three: a loaded
                # machine may drop one of them from the best-effort queue before the node reads it)
                bad = cv.joint_state_msg(ROBOT, ns, qj, np.zeros(ROBOT.n_joints), np.zeros(ROBOT.n_joints))
                bad.position[3] = float("nan")
                pubs["/joint_states"].publish(bad)
            else:
                pubs["/joint_states"].publish(cv.joint_state_msg(ROBOT, ns, qj, np.zeros(ROBOT.n_joints),
                                                                 np.zeros(ROBOT.n_joints)))
            time.sleep(0.004)
        torque = [m for m in cmds[n_before:] if m.mode == TorqueCommand.MODE_TORQUE]
        # then silence: damping again
        n_quiet = len(cmds)
        assert listener.wait_for(lambda: len(cmds) >= n_quiet + 20, timeout=10)
        after = cmds[n_quiet + 5:]
        time.sleep(1.2)  # one diagnostics period
        diags = [kv for d in listener.messages["/diagnostics"] for s in d.status if "id_controller" in s.name
                 for kv in s.values]
    finally:
        log = stop(node)
        listener.close()
    assert len(torque) > 100, log
    limits = ROBOT.torque_limits
    mg = ROBOT.total_mass * 9.81
    for m in torque:
        arr = cv.torque_command_arrays(ROBOT, m)  # rejects non-finite values
        assert np.all(np.abs(arr.feedforward + arr.feedback_linearization) <= limits + 1e-9)
        assert np.allclose(arr.position_target, q_stand[7:]) and np.all(arr.stiffness == 300.0)
    # the feedforward is the QP's standing torque at the reference (independent of the measured state)
    from ciml_control.controller import IdController

    expected = IdController(ROBOT).compute(ref.q, ref.v, ref.contacts, ref, np.zeros(ROBOT.nv))
    assert expected.contact_forces[:, 2].sum() == pytest.approx(mg, rel=1e-3)
    def last(phase: str, n: int = 20):
        """Feedforward of the last n commands computed for the joint states of a phase (stamped
        with them: a loaded machine may drop some best-effort states, so counts are not fixed)."""
        return [cv.torque_command_arrays(ROBOT, m).feedforward for m in torque
                if phases.get(cv.stamp_to_ns(m.header.stamp)) == phase][-n:]

    assert len(last("nominal")) == 20 and all(np.allclose(ff, expected.feedforward, atol=1e-3)
                                              for ff in last("nominal"))
    # with the prediction: the feedforward of the QP with ε = J'ᵀ Φ̃' − Sᵀ Γ (eq. 17) at the reference
    from ciml_learning.core.dynamics import RigidBodyDynamics, selection_matrix
    from ciml_learning.core.extraction import combined_error
    from ciml_learning.core.projection import contact_invariant_basis

    basis = contact_invariant_basis(RigidBodyDynamics(ROBOT).foot_jacobians(ref.q), ROBOT.leg_joints)
    eps = combined_error(basis, phi, gamma, selection_matrix(ROBOT))
    with_eps = IdController(ROBOT).compute(ref.q, ref.v, ref.contacts, ref, eps)
    assert with_eps.contact_forces[:, 2].sum() == pytest.approx(mg + 60.0, rel=1e-3)
    assert len(last("confident")) == 20 and all(np.allclose(ff, with_eps.feedforward, atol=1e-3)
                                                for ff in last("confident"))
    # a prediction less certain than the prior is not trusted: the nominal feedforward
    assert len(last("uncertain")) == 20 and all(np.allclose(ff, expected.feedforward, atol=1e-3)
                                                for ff in last("uncertain"))
    # 1e6 N is clipped to the robot's weight m·g: the QP plans for twice the weight
    eps_clipped = np.zeros(ROBOT.nv)
    eps_clipped[2] = mg
    clipped = IdController(ROBOT).compute(ref.q, ref.v, ref.contacts, ref, eps_clipped)
    assert not clipped.qp_failed and clipped.contact_forces[:, 2].sum() == pytest.approx(2 * mg, rel=1e-3)
    assert len(last("huge")) == 20 and all(np.allclose(ff, clipped.feedforward, atol=1e-3) for ff in last("huge"))
    # without predictions (older than model_error_timeout, 0.1 s) the controller keeps commanding torque
    # with the nominal model
    gone = [m for m in cmds if phases.get(cv.stamp_to_ns(m.header.stamp)) == "server_gone"]
    assert all(m.mode == TorqueCommand.MODE_TORQUE for m in gone)
    assert len(gone) >= 40 and all(np.allclose(ff, expected.feedforward, atol=1e-3) for ff in last("server_gone"))
    assert all(m.mode == TorqueCommand.MODE_DAMPING for m in after)
    keys = {kv.key: kv.value for kv in diags}
    assert int(keys.get("rejected_joint_states", 0)) >= 1, keys
    assert int(keys.get("stale_state", 0)) >= 1, keys
    assert int(keys.get("model_error_used", 0)) >= 60, keys
    assert int(keys.get("epsilon_gated", 0)) >= 20, keys
    assert int(keys.get("epsilon_clipped", 0)) >= 20, keys


@pytest.mark.ros
def test_id_controller_holds_a_late_reference_then_damps_a_dead_one():
    """/reference stops while the states go on: up to `reference_hold` (0.5 s) after it the
    controller still commands torque, holding the last reference pose (velocity targets 0,
    counted reference_held); after that, damping (counted stale_reference)."""
    from ciml_msgs.msg import ContactState, RobotReference, TorqueCommand
    from diagnostic_msgs.msg import DiagnosticArray
    from nav_msgs.msg import Odometry
    from sensor_msgs.msg import JointState

    listener = Listener({"/torque_command": TorqueCommand, "/diagnostics": DiagnosticArray})
    pubs = {"/reference": listener.node.create_publisher(RobotReference, "/reference", 10),
            "/joint_states": listener.node.create_publisher(JointState, "/joint_states", 10),
            "/base_state": listener.node.create_publisher(Odometry, "/base_state", 10),
            "/contact_state": listener.node.create_publisher(ContactState, "/contact_state", 10)}
    node = start_node("id_controller")
    cmds = listener.messages["/torque_command"]
    q_stand = standing_configuration(ROBOT, 0.002)
    motion = make_reference(ROBOT, "base_only", q_stand)
    zeros = np.zeros(ROBOT.n_joints)
    sent: dict[int, float] = {}   # joint-state stamp → wall time since the last reference [s]
    try:
        assert listener.wait_for(lambda: all(p.get_subscription_count() >= 1 for p in pubs.values()), 30), stop(node)
        last_ref, t_last = None, 0.0
        for k in range(500):
            ns = time.time_ns()
            if k < 250:  # a moving reference for 1 s, then none
                last_ref, t_last = motion.sample(1.0 + 0.004 * k), time.monotonic()
                pubs["/reference"].publish(reference_msg(ROBOT, ns, last_ref))
            sent[ns] = time.monotonic() - t_last if k >= 250 else -1.0
            pubs["/base_state"].publish(cv.odometry_msg(ns, q_stand[:3], q_stand[3:7], np.zeros(3), np.zeros(3)))
            pubs["/contact_state"].publish(cv.contact_state_msg(ROBOT, ns, np.ones(4, bool)))
            pubs["/joint_states"].publish(cv.joint_state_msg(ROBOT, ns, q_stand[7:], zeros, zeros))
            time.sleep(0.004)
        time.sleep(1.2)  # one diagnostics period
        keys = {kv.key: kv.value for d in listener.messages["/diagnostics"] for s in d.status
                if "id_controller" in s.name for kv in s.values}
    finally:
        log = stop(node)
        listener.close()
    assert np.linalg.norm(last_ref.v[6:]) > 1e-3  # the held reference was moving
    hold = ID_CONTROLLER.defaults["reference_hold"]
    by_age = [(sent[cv.stamp_to_ns(m.header.stamp)], t - t_last, m)
              for m, t in zip(cmds, listener.received["/torque_command"])
              if cv.stamp_to_ns(m.header.stamp) in sent]
    # Held: the controller received the last reference after the test sent it (t_last) and made
    # the command before the test received it, so a command received less than reference_hold
    # after t_last answered a reference younger than that by the controller's clock, whatever
    # the delivery delay; sent ≥ 0.15 s after it, that reference is the last one.
    held = [m for age, since_last, m in by_age if age >= 0.15 and since_last < hold]
    dead = [m for age, _, m in by_age if age >= 0.75]
    assert len(held) >= 20 and len(dead) >= 20, (len(held), len(dead), log[-800:])
    for m in held:
        arr = cv.torque_command_arrays(ROBOT, m)
        assert m.mode == TorqueCommand.MODE_TORQUE
        assert np.allclose(arr.position_target, last_ref.q[7:]) and np.allclose(arr.velocity_target, 0.0)
    assert all(m.mode == TorqueCommand.MODE_DAMPING for m in dead)
    assert int(keys.get("reference_held", 0)) >= 20 and int(keys.get("stale_reference", 0)) >= 20, keys


def _in_process(node_class, **params):
    """(node, context) of a node built in a private rclpy Context with `params` as overrides."""
    import random

    import rclpy
    from rclpy.parameter import Parameter

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=random.SystemRandom().randint(1, 101))
    try:
        return node_class(context=ctx, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()]), ctx
    except BaseException:
        rclpy.try_shutdown(context=ctx)
        raise


def _feed_standing(node, robot, ns: int, qj=None, model_error=None) -> None:
    """One sample of a standing robot (reference, base, contacts, optional prediction, then the
    joint state that triggers the control step), handed to the node's callbacks."""
    q_stand = standing_configuration(robot, 0.002)
    ref = make_reference(robot, "stand", q_stand).sample(0.0)
    node.on_reference(reference_msg(robot, ns, ref))
    node.on_base(cv.odometry_msg(ns, q_stand[:3], q_stand[3:7], np.zeros(3), np.zeros(3)))
    node.on_contacts(cv.contact_state_msg(robot, ns, np.ones(robot.n_feet, bool)))
    if model_error is not None:
        node.on_model_error(model_error)
    qj = q_stand[7:] if qj is None else qj
    node.on_joints(cv.joint_state_msg(robot, ns, qj, np.full(robot.n_joints, 0.1), np.zeros(robot.n_joints)))


@pytest.mark.ros
@pytest.mark.parametrize("wait", [False, True])
def test_a_late_reference_is_waited_for_in_lockstep_and_held_otherwise(wait):
    """A joint sample whose /reference is 0.2 s old (reference_timeout 0.1 s): with
    wait_for_reference (a lockstep simulator) no command until a fresh reference arrives, then one
    for that same joint sample at the new reference (counted reference_waits); without it, at once,
    the last pose held (counted reference_held)."""
    import rclpy
    from ciml_msgs.msg import TorqueCommand

    from ciml_control.nodes.id_controller import IdControllerNode

    node, ctx = _in_process(IdControllerNode, wait_for_reference=wait)
    try:
        clock = [1.0]
        node._now = lambda: clock[0]  # the node clock under the test's control
        commands = []
        node.pub.publish = commands.append
        _feed_standing(node, ROBOT, 10**9)
        assert len(commands) == 1 and commands[0].mode == TorqueCommand.MODE_TORQUE
        clock[0], ns = 1.2, 12 * 10**8
        q_stand = standing_configuration(ROBOT, 0.002)
        node.on_base(cv.odometry_msg(ns, q_stand[:3], q_stand[3:7], np.zeros(3), np.zeros(3)))
        node.on_contacts(cv.contact_state_msg(ROBOT, ns, np.ones(ROBOT.n_feet, bool)))
        node.on_joints(cv.joint_state_msg(ROBOT, ns, q_stand[7:], np.zeros(12), np.zeros(12)))
        if wait:
            assert len(commands) == 1 and node.health.counts["reference_waits"] == 1
            # 0.3 s into base_only: 4 mm from the stand (a leap beyond resume_tolerance would stop the robot)
            ref = make_reference(ROBOT, "base_only", q_stand).sample(0.3)
            node.on_reference(reference_msg(ROBOT, ns, ref))
            target = ref.q[7:]
        else:
            target = make_reference(ROBOT, "stand", q_stand).sample(0.0).q[7:]
            assert node.health.counts["reference_held"] == 1
        assert len(commands) == 2 and cv.stamp_to_ns(commands[1].header.stamp) == ns
        assert commands[1].mode == TorqueCommand.MODE_TORQUE
        assert np.allclose(cv.torque_command_arrays(ROBOT, commands[1]).position_target, target)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_in_lockstep_a_reference_stamped_behind_the_sample_is_waited_for():
    """wait_for_reference: a /reference received just now but stamped 0.1 s before the joint
    sample (its node stalled and is catching up) is not used (max_reference_lag 0.02 s): the
    sample waits; one stamped 4 ms before it is answered at once."""
    import rclpy

    from ciml_control.nodes.id_controller import IdControllerNode

    node, ctx = _in_process(IdControllerNode, wait_for_reference=True)
    try:
        clock = [1.0]
        node._now = lambda: clock[0]
        commands = []
        node.pub.publish = commands.append
        _feed_standing(node, ROBOT, 10**9)
        assert len(commands) == 1
        q_stand = standing_configuration(ROBOT, 0.002)
        stand = make_reference(ROBOT, "stand", q_stand).sample(0.0)
        clock[0], ns = 1.1, 11 * 10**8
        node.on_reference(reference_msg(ROBOT, ns - 10**8, stand))  # received now, stamped 0.1 s behind
        node.on_base(cv.odometry_msg(ns, q_stand[:3], q_stand[3:7], np.zeros(3), np.zeros(3)))
        node.on_contacts(cv.contact_state_msg(ROBOT, ns, np.ones(ROBOT.n_feet, bool)))
        node.on_joints(cv.joint_state_msg(ROBOT, ns, q_stand[7:], np.zeros(12), np.zeros(12)))
        assert len(commands) == 1 and node.health.counts["reference_waits"] == 1
        node.on_reference(reference_msg(ROBOT, ns - 4 * 10**6, stand))  # caught up: the sample is answered
        assert len(commands) == 2 and cv.stamp_to_ns(commands[1].header.stamp) == ns
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_id_controller_publishes_a_ros2_control_effort_array_in_the_profiles_joint_order(tmp_path):
    """effort_command_topic: each command also as std_msgs/Float64MultiArray, the joint-loop law's
    torque at the sample (clipped to the limits) in the order of the profile's effort-array
    joints (here go1 with its legs listed FR, FL, RR, RL); damping commands too; a profile whose
    array misses a joint stops the node at start with one line."""
    import rclpy
    import yaml

    from ciml_control.conversions import effort_joint_order
    from ciml_control.nodes.id_controller import IdControllerNode
    from ciml_learning.core.errors import CimlError
    from ciml_learning.core.profile import load_profile, shipped_profile

    data = yaml.safe_load(open(shipped_profile("go1")))
    data["urdf"] = load_profile("go1").urdf
    legs = ["FR", "FL", "RR", "RL"]
    joints = [f"{leg}_{j}_joint" for leg in legs for j in ("hip", "thigh", "calf")]
    data["inputs"]["command"] = {"topic": "/effort_controller/commands", "type": "std_msgs/msg/Float64MultiArray",
                                 "field": "data", "joints": joints}
    path = tmp_path / "go1_effort.yaml"
    path.write_text(yaml.safe_dump(data))
    robot = load_profile(str(path)).robot()
    order = effort_joint_order(load_profile(str(path)), robot)
    assert [robot.joint_names[i] for i in order] == joints and list(order) != list(range(12))

    node, ctx = _in_process(IdControllerNode, robot=str(path), effort_command_topic="/effort_controller/commands")
    try:
        commands, arrays = [], []
        node.pub.publish, node.effort_pub.publish = commands.append, arrays.append
        rng = np.random.default_rng(1)
        q_stand = standing_configuration(robot, 0.002)
        for k in range(5):
            qj = q_stand[7:] + 0.8 * rng.standard_normal(12)  # far from the target: some torques at their limits
            _feed_standing(node, robot, 10**9 + k * 4_000_000, qj)
            cmd = cv.torque_command_arrays(robot, commands[-1])
            u = cmd.total(qj, np.full(12, 0.1), robot.torque_limits)
            assert len(arrays) == k + 1 and np.allclose(arrays[-1].data, u[order], atol=1e-12)
            assert np.all(np.abs(arrays[-1].data) <= robot.torque_limits[order] + 1e-12)
        assert np.any(np.abs(u) >= robot.torque_limits - 1e-9)  # the clipping was exercised
        node.publish_damping("stale_state", "test", 2 * 10**9)  # damping: u = −d q̇ at the last sample
        assert np.allclose(arrays[-1].data, -node.damping_gain * 0.1 * np.ones(12))
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)

    data["inputs"]["command"]["joints"] = joints[:-1]
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(CimlError) as err:
        _in_process(IdControllerNode, robot=str(path))
    assert "inputs.command.joints" in str(err.value) and "\n" not in str(err.value)


@pytest.mark.ros
def test_feedforward_only_publishes_the_learned_correction_and_commands_nothing():
    """feedforward_only: no /torque_command at all; /model_error/feedforward carries, per joint
    sample (its stamp, the robot's joint names), the QP feedforward with the trusted ε minus the
    nominal one: zero without a prediction, the learned correction with a confident one."""
    import rclpy

    from ciml_control.controller import IdController
    from ciml_control.nodes.id_controller import IdControllerNode

    node, ctx = _in_process(IdControllerNode, feedforward_only=True)
    try:
        commands, corrections = [], []
        node.pub.publish, node.feedforward_pub.publish = commands.append, corrections.append
        _feed_standing(node, ROBOT, 10**9)  # no prediction: the nominal model, no correction
        assert len(corrections) == 1 and np.allclose(corrections[0].effort, 0.0, atol=1e-9)
        phi = np.zeros(18)
        phi[2] = 60.0  # 60 N more weight on the base
        gamma = np.full(ROBOT.n_joints, -2.0)  # every actuator 2 Nm short
        ns = 10**9 + 4_000_000
        prediction = cv.model_error_msg(ROBOT, ns, "test", phi, np.ones(18, bool), gamma,
                                        np.ones(ROBOT.n_joints, bool))
        _feed_standing(node, ROBOT, ns, model_error=prediction)
        msg = corrections[-1]
        assert list(msg.name) == list(ROBOT.joint_names) and cv.stamp_to_ns(msg.header.stamp) == ns
        # the same correction from the controller law itself, with the ε the node trusted
        ref = node.reference[2]
        eps, _ = node.epsilon(ref, node.reference[1], node._now())
        q_stand = standing_configuration(ROBOT, 0.002)
        v = np.r_[np.zeros(6), np.full(ROBOT.n_joints, 0.1)]
        ctl = IdController(ROBOT)
        expected = (ctl.compute(q_stand, v, np.ones(4, bool), ref, eps).feedforward
                    - ctl.compute(q_stand, v, np.ones(4, bool), ref, np.zeros(ROBOT.nv)).feedforward)
        assert np.linalg.norm(expected) > 5.0 and np.allclose(msg.effort, expected, atol=1e-6)
        assert commands == [] and not node.commanding and node.health.message == "feedforward only"
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_the_trust_gate_works_in_the_coordinates_the_model_predicted():
    """A model set predicts Φ̃ = J'ᵀΦ̃' and its variance: an entry of Φ̃ less certain than its prior is
    not used, whatever the variance mapped to Φ̃' says (that map drops the covariances, and gated in
    Φ̃' go1's uncertain base pitch torque passed). Without Φ̃'s variance the gate works in Φ̃'."""
    import rclpy

    from ciml_control.nodes.id_controller import IdControllerNode
    from ciml_control.trust import GENERALIZED
    from ciml_learning.core.dynamics import selection_matrix
    from ciml_learning.core.projection import contact_invariant_basis

    node, ctx = _in_process(IdControllerNode)
    try:
        node.pub.publish = lambda msg: None
        rng = np.random.default_rng(0)
        phi, gamma = rng.normal(scale=5.0, size=18), rng.normal(size=ROBOT.n_joints)
        confident_r, confident_a = np.full(18, 1e-6), np.full(ROBOT.n_joints, 1e-6)
        generalized = node.trust.prior_variance[GENERALIZED] * 1e-3
        generalized[4] = 2.0 * node.trust.prior_variance[GENERALIZED][4]  # the base pitch torque: unknown
        eps = {}
        for k, gen in enumerate((generalized, None)):
            ns = 10**9 + 4_000_000 * k
            prediction = cv.model_error_msg(ROBOT, ns, "test", phi, np.ones(18, bool), gamma,
                                            np.ones(ROBOT.n_joints, bool), confident_r, confident_a, gen)
            gated_before = node.health.counts["epsilon_gated"]
            _feed_standing(node, ROBOT, ns, model_error=prediction)
            assert node.health.counts["epsilon_gated"] == gated_before + (gen is not None)
            eps[k] = node.epsilon(node.reference[2], ns, node._now())[0]
        basis = contact_invariant_basis(node.controller.desired_terms(node.reference[2])[2], ROBOT.leg_joints)
        expected = basis.T @ phi - selection_matrix(ROBOT).T @ gamma
        np.testing.assert_allclose(eps[1], expected, atol=1e-9)  # nothing gated in Φ̃'
        expected[4] = 0.0  # Φ̃'s entry 4 gated; Γ does not reach the base rows
        np.testing.assert_allclose(eps[0], expected, atol=1e-9)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


@pytest.mark.ros
def test_model_error_predicted_as_a_feedforward_without_a_model():
    """/model_error/predicted as a user's controller reads it (docs/LIVE_GRAPH.md): one message per
    /reference, stamped with the reference's stamp, Γ by joint name in the robot's joint order [Nm],
    Φ̃' by name (base wrench [N, Nm], then 3 per foot [N]); without a served model it is the
    nominal model: source 'nominal', zeros, nothing observed, the prior variances (large)."""
    import rclpy

    from ciml_learning.core.profile import load_profile
    from ciml_learning.nodes.model_server import ModelServerNode

    robot = load_profile("go1").robot()
    node, ctx = _in_process(ModelServerNode, robot="go1")
    try:
        out = []
        node.pub.publish = out.append
        ref = make_reference(robot, "trot_35", standing_configuration(robot, 0.002)).sample(2.0)
        node.on_reference(reference_msg(robot, 123_456_789, ref))
        (msg,) = out
        assert cv.stamp_to_ns(msg.header.stamp) == 123_456_789 and msg.source == "nominal"
        assert list(msg.actuation_names) == list(robot.joint_names)
        assert list(msg.rbd_names) == list(robot.rbd_error_names)
        assert not any(msg.actuation_observed) and not any(msg.rbd_observed)
        assert np.all(np.asarray(msg.actuation_error) == 0) and np.all(np.asarray(msg.rbd_error) == 0)
        assert np.all(np.asarray(msg.actuation_variance) > 0) and np.all(np.asarray(msg.rbd_variance) > 0)
        assert len(msg.generalized_variance) == robot.nv and np.all(np.asarray(msg.generalized_variance) > 0)
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)
