"""Gait references: kinematic consistency, contact schedule, limits (issue 5 evidence)."""
import numpy as np
import pinocchio as pin
import pytest

from ciml_control import references as refs
from ciml_control.references import MOTIONS, UnknownMotionError, default_duration, make_reference
from ciml_learning.core.errors import CimlError


def _sample_motion(robot, q_stand, motion, dt=0.02):
    ref = make_reference(robot, motion, q_stand)
    ts = np.arange(0.0, default_duration(motion), dt)
    return ref, ts, [ref.sample(t) for t in ts]


def _feet(robot, q):
    data = robot.model.createData()
    pin.framesForwardKinematics(robot.model, data, q)
    return np.array([data.oMf[f].translation.copy() for f in robot.foot_frame_ids])


@pytest.fixture(scope="module")
def sampled(robot, q_stand):
    return {m: _sample_motion(robot, q_stand, m) for m in MOTIONS}


def test_unknown_motion_names_valid_ones(robot, q_stand):
    with pytest.raises(UnknownMotionError, match="trot_35") as info:
        make_reference(robot, "moonwalk", q_stand)
    assert isinstance(info.value, CimlError)
    assert "moonwalk" in str(info.value)
    with pytest.raises(CimlError):
        default_duration("moonwalk")


def test_default_durations():
    assert default_duration("stand") == 20.0
    assert default_duration("base_only") == 20.0
    for m in MOTIONS[2:]:
        period = refs.spec(m).period
        assert default_duration(m) == pytest.approx(refs.SETTLE_TIME + 10 * period)


def test_starts_at_standing_pose_at_rest(robot, q_stand, sampled):
    for m in MOTIONS:
        p = sampled[m][2][0]
        assert np.allclose(p.q, q_stand, atol=1e-9), m
        assert np.allclose(p.v, 0.0, atol=1e-9) and np.allclose(p.a, 0.0, atol=1e-9), m
        assert p.contacts.all() and p.motion == m and 0.0 <= p.phase < 1.0


@pytest.mark.parametrize("motion", MOTIONS)
def test_stance_feet_fixed_in_world(robot, sampled, motion):
    """A foot in stance in consecutive samples does not move (1e-6 m) and has zero velocity."""
    _, ts, pts = sampled[motion]
    feet = np.array([_feet(robot, p.q) for p in pts])
    contacts = np.array([p.contacts for p in pts])
    both = contacts[1:] & contacts[:-1]
    moved = np.linalg.norm(feet[1:] - feet[:-1], axis=2)
    assert both.any()
    assert moved[both].max() < 1e-6
    data = robot.model.createData()
    for p in pts[::10]:
        pin.computeJointJacobians(robot.model, data, p.q)
        pin.updateFramePlacements(robot.model, data)
        for i, f in enumerate(robot.foot_frame_ids):
            if p.contacts[i]:
                J = pin.getFrameJacobian(robot.model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3]
                assert np.linalg.norm(J @ p.v) < 1e-9


@pytest.mark.parametrize("motion", MOTIONS)
def test_joint_limits_respected(robot, sampled, motion):
    lo, hi = robot.position_limits
    Q = np.array([p.q[7:] for p in sampled[motion][2]])
    assert np.all(Q >= lo) and np.all(Q <= hi)


@pytest.mark.parametrize("motion", MOTIONS)
def test_velocity_and_acceleration_match_finite_differences(robot, q_stand, motion):
    """q̇ᵈ = d/dt qᵈ (on the configuration manifold) and q̈ᵈ = d/dt q̇ᵈ, central differences."""
    ref = make_reference(robot, motion, q_stand)
    h = 1e-4
    rng = np.random.default_rng(1)
    for t in rng.uniform(0.0, default_duration(motion), 25):
        p, pp, pm = ref.sample(t), ref.sample(t + h), ref.sample(t - h)
        v_fd = (pin.difference(robot.model, p.q, pp.q) - pin.difference(robot.model, p.q, pm.q)) / (2 * h)
        a_fd = (pp.v - pm.v) / (2 * h)
        assert np.allclose(v_fd, p.v, atol=1e-5 * max(1.0, np.abs(p.v).max())), (motion, t)
        assert np.allclose(a_fd, p.a, atol=1e-4 * max(1.0, np.abs(p.a).max())), (motion, t)


@pytest.mark.parametrize("motion", [m for m in MOTIONS if refs.spec(m).kind in ("walk", "trot")])
def test_gait_progression_per_cycle(robot, sampled, motion):
    """After the ramp, the base advances one step length per gait cycle, in the motion's direction."""
    ref, ts, pts = sampled[motion]
    s = refs.spec(motion)
    t_a = ref.t0 + 8 * s.period
    pa, pb = ref.sample(t_a), ref.sample(t_a + s.period)
    disp = pb.q[:2] - pa.q[:2]
    assert np.allclose(disp, s.step_length * np.asarray(s.direction), atol=1e-6)
    # every foot swings once per cycle and lands one step length further
    feet_a, feet_b = _feet(robot, pa.q), _feet(robot, pb.q)
    assert np.allclose(feet_b[:, :2] - feet_a[:, :2], disp, atol=1e-6)


@pytest.mark.parametrize("motion", [m for m in MOTIONS if refs.spec(m).kind == "walk"])
def test_static_walk_one_leg_at_a_time_com_in_support_triangle(robot, sampled, motion):
    _, ts, pts = sampled[motion]
    data = robot.model.createData()
    swings = 0
    for p in pts:
        n_swing = int(np.count_nonzero(~p.contacts))
        assert n_swing <= 1
        if n_swing == 1:
            swings += 1
            com = pin.centerOfMass(robot.model, data, p.q)[:2]
            tri = _feet(robot, p.q)[p.contacts][:, :2]
            assert _inside_margin(com, tri) > 0.02, (motion, p.t)
            assert np.allclose(p.a[:3], 0.0, atol=1e-9)  # base at rest while a leg swings
    assert swings > 0


def _inside_margin(point, tri):
    """Signed distance of a point from the edges of a triangle (positive inside)."""
    c = tri.mean(axis=0)
    margins = []
    for k in range(3):
        a, b = tri[k], tri[(k + 1) % 3]
        e = b - a
        n = np.array([e[1], -e[0]]) / np.linalg.norm(e)
        if n @ (c - a) < 0:
            n = -n
        margins.append(n @ (point - a))
    return min(margins)


@pytest.mark.parametrize("motion", ["trot_20", "trot_35", "trot_45"])
def test_trot_swings_diagonal_pairs(robot, sampled, motion):
    _, _, pts = sampled[motion]
    rel = _feet(robot, pts[0].q)[:, :2] - _feet(robot, pts[0].q)[:, :2].mean(axis=0)
    seen = set()
    for p in pts:
        swing = tuple(np.flatnonzero(~p.contacts))
        if swing:
            assert len(swing) == 2
            a, b = rel[list(swing)]
            assert np.sign(a[0]) != np.sign(b[0]) and np.sign(a[1]) != np.sign(b[1])  # diagonal
            seen.add(swing)
    assert len(seen) == 2


@pytest.mark.parametrize("motion", ["walk_30", "trot_35"])
def test_swing_height(robot, sampled, motion):
    _, _, pts = sampled[motion]
    feet = np.array([_feet(robot, p.q) for p in pts])
    lift = feet[:, :, 2] - feet[0, :, 2]
    assert lift.min() > -1e-9
    assert lift.max() == pytest.approx(refs.spec(motion).step_height, rel=0.05)


def test_base_only_follows_waypoints_with_feet_fixed(robot, q_stand, sampled):
    ref, ts, pts = sampled["base_only"]
    assert all(p.contacts.all() for p in pts)
    feet0 = _feet(robot, q_stand)
    for p in pts[::25]:
        assert np.allclose(_feet(robot, p.q), feet0, atol=1e-9)
    period = refs.BASE_ONLY_PERIOD
    n_wp = len(refs.BASE_ONLY_WAYPOINTS) - 1
    for k in range(n_wp):
        t = period + k * period / n_wp  # after the fade-in
        p = ref.sample(t)
        offset = refs.BASE_ONLY_WAYPOINTS[k]
        assert np.allclose(p.q[:3], q_stand[:3] + offset[:3], atol=1e-9)
        rpy = pin.rpy.matrixToRpy(pin.Quaternion(p.q[3:7]).matrix())
        assert np.allclose(rpy, offset[3:], atol=1e-9)


def test_samples_are_deterministic(robot, q_stand):
    a = make_reference(robot, "trot_35", q_stand)
    b = make_reference(robot, "trot_35", q_stand)
    for t in (2.345, 0.5, 4.1):
        b.sample(t + 0.01)
        pa, pb = a.sample(t), b.sample(t)
        assert np.allclose(pa.q, pb.q, atol=1e-9) and np.allclose(pa.v, pb.v, atol=1e-7)


def test_bad_q_stand_rejected(robot):
    with pytest.raises(CimlError):
        make_reference(robot, "stand", np.full(robot.nq, np.nan))


@pytest.mark.parametrize("motion", ["trot_20", "trot_45"])
def test_trot_sway_cuts_the_moment_the_contacts_cannot_give(robot, q_stand, motion):
    """With two feet on a line no joint torque makes a moment about it; the lateral sway
    (GaitReference.trot_sway) cuts what the reference asks there — the QP's `unrealizable`
    part — to a fraction of the straight path's, without a QP failure."""
    from ciml_control.controller import IdController

    def unrealizable_rms(ref):
        ctrl = IdController(robot)
        ts = np.arange(4.0, 5.2, 0.008)  # two cycles after the velocity ramp and the sway's fade-in
        u = [ctrl.compute(p.q, p.v, p.contacts, p).unrealizable for p in (ref.sample(t) for t in ts)]
        assert ctrl.qp_failures == 0
        return float(np.sqrt(np.mean(np.square(u))))

    straight = make_reference(robot, motion, q_stand)
    straight.trot_sway = lambda t: (0.0, 0.0, 0.0)
    assert unrealizable_rms(make_reference(robot, motion, q_stand)) < 0.35 * unrealizable_rms(straight)


@pytest.mark.parametrize("motion", ["trot_35", "trot_45"])
def test_a_sample_at_a_contact_switch_takes_the_motion_after_it_however_t_rounds(robot, q_stand, motion):
    """The trot's lateral acceleration jumps at each switch of the diagonal pairs (the support line
    changes). A sample at a switch instant commands the 4 ms after it, so it must take that motion
    whether its time falls a rounding error before or after the switch: live stamps (ns · 1e-9
    from the reference generator's start) fell on the other side after ~300 s, and go1's learned
    ε then cost 21 % more feedback effort."""
    ref = make_reference(robot, motion, q_stand)
    half = 0.5 * ref.period
    for k in (20, 21, 1001, 1002, 12001):  # ~7 s, ~300 s and ~1 h after the start
        t_switch = ref.t0 + k * half
        after = ref.sample(t_switch + 1e-7).a
        for t in (t_switch - 1e-12, t_switch, t_switch + 1e-12, round(t_switch * 1e9) * 1e-9):
            a = ref.sample(t).a
            assert np.allclose(a, after, atol=1e-3), (k, t - t_switch, np.abs(a - after).max())
