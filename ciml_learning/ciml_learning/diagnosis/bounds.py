"""Physical bounds of every catalogue parameter, in one place (docs/DIAGNOSIS.md).

A parameter outside these ranges is not a property of a robot: a 0.06 kg foot does not weigh
two tonnes, an encoder is not mounted 10° off, friction does not push. The identification
fits inside them (bounded least squares, identification.bounded_least_squares), and an
estimate that ends on a bound that is not the parameter's null value ("no effect") is
reported as "at bound — not identified", with no confidence, never as an effect.

Where a bound scales with the robot it is derived from its description (total mass, torque
limits); the fractions and angles are stated here. In the linear parameters θ of the
candidates (candidates.py):

    payload                mass m ∈ [0, PAYLOAD_MASS_FRACTION · robot mass],
                           m·c_i ∈ ±m_max · PAYLOAD_LEVER (and ‖c‖ ≤ PAYLOAD_LEVER after the fit)
    link_mass_scale        s ∈ LINK_MASS_SCALE                     θ = s − 1
    encoder_offset         |δ| ≤ MAX_ANGLE                         θ = δ [rad]
    base_imu_tilt          |roll|, |pitch| ≤ MAX_ANGLE             θ = angles [rad]
    joint Coulomb          0 ≤ f_c ≤ FRICTION_FRACTION · τ_max      θ = f_c [Nm]
    joint viscous          0 ≤ b ≤ FRICTION_FRACTION · τ_max / (1 rad/s)
    actuator_lag           T ∈ [0, MAX_LAG]                        θ = T/g ∈ [0, MAX_LAG / g_min]
    torque_gain            g ∈ TORQUE_GAIN                          θ = 1 − 1/g
    torque_offset          |o| ≤ OFFSET_FRACTION · τ_max            θ = o/g
    torque_sensor_gain     g_s ∈ TORQUE_GAIN                        θ = 1 − 1/g_s
    torque_sensor_offset   |o_s| ≤ OFFSET_FRACTION · τ_max          θ = o_s/g_s
    command-update sampling (the baseline): theory gives qd = −K_p Δt/2 ≤ 0, qdd = −K_d Δt/2 ≤ 0,
                           udot = −Δt/2 ∈ [−MAX_TICK/2, 0] (Δt the controller tick)

τ_max is the joint's URDF effort limit (FALLBACK_TORQUE_LIMIT where the URDF gives none).
"""
from __future__ import annotations

import math

import numpy as np

PAYLOAD_MASS_FRACTION = 1.0
"""A payload weighs at most this multiple of the robot's own mass."""
PAYLOAD_LEVER = 1.0
"""[m] a payload's CoM lies at most this far from the base origin."""
LINK_MASS_SCALE = (0.2, 5.0)
"""A link's true mass lies within this factor range of its URDF mass."""
MAX_ANGLE = math.radians(5.0)
"""[rad] largest encoder offset and IMU tilt (a few degrees: more is a mounting error one sees)."""
FRICTION_FRACTION = 0.5
"""Joint friction (Coulomb [Nm], viscous [Nm at 1 rad/s]) is at most this fraction of the torque limit."""
MAX_LAG = 0.1
"""[s] largest actuator time constant."""
TORQUE_GAIN = (0.5, 2.0)
"""Range of an actuator's or torque sensor's gain."""
OFFSET_FRACTION = 0.2
"""A torque offset is at most this fraction of the torque limit."""
MAX_TICK = 0.1
"""[s] longest controller tick of a log (the baseline's udot ≥ −MAX_TICK/2)."""
FALLBACK_TORQUE_LIMIT = 1000.0
"""[Nm] torque limit of a joint whose URDF gives none (0 or not finite)."""


def torque_limits(robot) -> np.ndarray:
    lim = np.asarray(robot.torque_limits, float)
    return np.where(np.isfinite(lim) & (lim > 0), lim, FALLBACK_TORQUE_LIMIT)


def gain_theta(g: tuple[float, float]) -> tuple[float, float]:
    """θ = 1 − 1/g range of a gain range."""
    return 1.0 - 1.0 / g[0], 1.0 - 1.0 / g[1]


def parameter_bounds(robot, cand_type: str, joint: str | None = None) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """(lower, upper) of a candidate's linear parameters θ (module docstring)."""
    lim = torque_limits(robot)
    tmax = float(lim[robot.joint_names.index(joint)]) if joint is not None else float(np.max(lim))
    if cand_type == "joint_coulomb_friction" or cand_type == "joint_viscous_friction":
        return (0.0,), (FRICTION_FRACTION * tmax,)
    if cand_type == "encoder_offset":
        return (-MAX_ANGLE,), (MAX_ANGLE,)
    if cand_type == "base_imu_tilt":
        return (-MAX_ANGLE, -MAX_ANGLE), (MAX_ANGLE, MAX_ANGLE)
    if cand_type == "payload":
        m_max = PAYLOAD_MASS_FRACTION * float(robot.total_mass)
        mc = m_max * PAYLOAD_LEVER
        return (0.0, -mc, -mc, -mc), (m_max, mc, mc, mc)
    if cand_type == "link_mass_scale":
        return (LINK_MASS_SCALE[0] - 1.0,), (LINK_MASS_SCALE[1] - 1.0,)
    if cand_type == "actuator_lag":
        return (0.0,), (MAX_LAG / TORQUE_GAIN[0],)
    if cand_type in ("torque_gain", "torque_sensor_gain"):
        lo, hi = gain_theta(TORQUE_GAIN)
        return (lo,), (hi,)
    if cand_type in ("torque_offset", "torque_sensor_offset"):
        o = OFFSET_FRACTION * tmax / TORQUE_GAIN[0]
        return (-o,), (o,)
    if cand_type == "command_update_sampling":
        return (-np.inf, -np.inf, -MAX_TICK / 2), (0.0, 0.0, 0.0)
    raise KeyError(cand_type)


def physical_ranges(robot) -> dict:
    """The bounds in the scenario's terms, for diagnosis.json (`bounds`) and the report."""
    friction_max = FRICTION_FRACTION * float(np.min(torque_limits(robot)))
    return {
        "payload": {"mass": [0.0, PAYLOAD_MASS_FRACTION * float(robot.total_mass)], "com_norm_max": PAYLOAD_LEVER},
        "link_mass_scale": {"value": list(LINK_MASS_SCALE)},
        "encoder_offset": {"value": [-MAX_ANGLE, MAX_ANGLE]},
        "base_imu_tilt": {"roll": [-MAX_ANGLE, MAX_ANGLE], "pitch": [-MAX_ANGLE, MAX_ANGLE]},
        "joint_coulomb_friction": {"value": [0.0, friction_max], "of_torque_limit": FRICTION_FRACTION},
        "joint_viscous_friction": {"value": [0.0, friction_max], "of_torque_limit": FRICTION_FRACTION},
        "actuator_lag": {"time_constant": [0.0, MAX_LAG]},
        "torque_gain": {"value": list(TORQUE_GAIN)},
        "torque_offset": {"value_of_torque_limit": [-OFFSET_FRACTION, OFFSET_FRACTION]},
        "torque_sensor_gain": {"value": list(TORQUE_GAIN)},
        "torque_sensor_offset": {"value_of_torque_limit": [-OFFSET_FRACTION, OFFSET_FRACTION]},
        "command_update_sampling": {"qd": [None, 0.0], "qdd": [None, 0.0], "udot": [-MAX_TICK / 2, 0.0]},
    }


def physical_violation(cand_type: str, params: dict) -> str | None:
    """Which physical parameter (in the scenario's terms) leaves its range after the conversion
    from θ (a lag T = c·g can exceed MAX_LAG while c is inside its box); None when all are inside."""
    tol = 1e-9
    if cand_type == "actuator_lag":
        T = params.get("time_constant", 0.0)
        if T > MAX_LAG * (1 + 1e-6) or T < -tol:
            return f"time_constant {T:.4g} s outside [0, {MAX_LAG}]"
    if cand_type in ("torque_gain", "torque_sensor_gain"):
        g = params.get("value", 1.0)
        if not (TORQUE_GAIN[0] * (1 - 1e-6) <= g <= TORQUE_GAIN[1] * (1 + 1e-6)):
            return f"gain {g:.4g} outside {list(TORQUE_GAIN)}"
    if cand_type == "payload":
        com = np.asarray(params.get("com", [0, 0, 0]), float)
        if np.linalg.norm(com) > PAYLOAD_LEVER * (1 + 1e-6):
            return f"CoM {np.linalg.norm(com):.3g} m from the base (> {PAYLOAD_LEVER} m)"
    return None
