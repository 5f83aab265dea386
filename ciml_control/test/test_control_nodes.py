"""reference_generator and id_controller on the live graph (DDS on loopback)."""
from __future__ import annotations

import time

import numpy as np
import pytest
from rosutil import Listener, start_node, stop

from ciml_control.conversions import reference_msg, reference_point
from ciml_control.references import make_reference, standing_configuration
from ciml_learning import conversions as cv
from ciml_learning.robot import load_robot

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
    from ciml_learning.dynamics import RigidBodyDynamics, selection_matrix
    from ciml_learning.extraction import combined_error
    from ciml_learning.projection import contact_invariant_basis

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
    by_age = [(sent[cv.stamp_to_ns(m.header.stamp)], m) for m in cmds if cv.stamp_to_ns(m.header.stamp) in sent]
    held = [m for age, m in by_age if 0.15 <= age <= 0.4]
    dead = [m for age, m in by_age if age >= 0.65]
    assert len(held) >= 20 and len(dead) >= 20, (len(held), len(dead), log[-800:])
    for m in held:
        arr = cv.torque_command_arrays(ROBOT, m)
        assert m.mode == TorqueCommand.MODE_TORQUE
        assert np.allclose(arr.position_target, last_ref.q[7:]) and np.allclose(arr.velocity_target, 0.0)
    assert all(m.mode == TorqueCommand.MODE_DAMPING for m in dead)
    assert int(keys.get("reference_held", 0)) >= 20 and int(keys.get("stale_reference", 0)) >= 20, keys
