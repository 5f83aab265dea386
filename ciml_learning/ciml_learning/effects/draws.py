"""Random hidden-effect cases for `ciml gap-bench --random N --seed S` (issue 31), drawn beside the registry.

Each case draws 0–3 effects (types, places, values), a sensor-noise level, training and held-out
motions and a simulation seed. A case is a scenario mapping (seed, sensor_noise, effects: the
registry's fields) plus its motions; `kind` says what the scorer expects ("nominal", "catalogue",
"out_of_catalogue").

Why a draw range per type besides the registry's bounds: the physical bounds (EffectType.physical_range)
say what no robot has (a Coulomb friction of half the torque limit), not what a walking robot
plausibly carries; a draw from them would mostly be a robot that falls. DRAW_RANGES are the sizes a
HyQ-class robot still walks with, and every one lies inside its field's simulator range and its
physical bounds (checked by draw_cases and by test_gapbench_random). The lower ends are small on
purpose: the detection limit per type is read off the draws that were, or were not, named.

Reproducible: case i depends on (seed, i) only, so the first cases of --random 20 are those of
--random 200 with the same seed.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ciml_learning.effects import CATALOGUE, EFFECTS, OUT_OF_CATALOGUE
from ciml_learning.effects.scenario import outside_range

REALISTIC_NOISE: dict[str, float] = {"q": 0.0005, "qd": 0.01, "tau": 0.5, "base_orientation": 0.001}
"""The realistic sensor noise of docs/ARCHITECTURE.md §5 (standard deviations); a case scales it."""

DRAW_RANGES: dict[str, dict[str, tuple[float, float]]] = {
    # magnitude ranges of each float field (|x − null|); SIGNED fields draw either sign
    "joint_coulomb_friction": {"value": (0.5, 12.0)},                 # Nm
    "joint_viscous_friction": {"value": (0.3, 5.0)},                  # Nm s/rad
    "joint_stribeck_friction": {"coulomb": (2.0, 8.0), "breakaway": (1.5, 3.0), "velocity": (0.05, 0.4)},
    "actuator_lag": {"time_constant": (0.002, 0.02)},                 # s
    "torque_gain": {"value": (0.03, 0.3)},                            # |g − 1|
    "torque_offset": {"value": (0.3, 5.0)},                           # Nm
    "payload": {"mass": (0.5, 12.0), "com": (0.0, 0.15)},             # kg, m (each component)
    "link_mass_scale": {"value": (0.05, 0.6)},                        # |s − 1|
    "encoder_offset": {"value": (0.002, 0.04)},                       # rad
    "base_imu_tilt": {"roll": (0.001, 0.015), "pitch": (0.001, 0.015)},  # rad
    "torque_sensor_gain": {"value": (0.03, 0.25)},                    # |g − 1|
    "torque_sensor_offset": {"value": (0.3, 5.0)},                    # Nm
    # outside the catalogue (the diagnosis has no candidate: it must say "unexplained")
    "joint_spring": {"stiffness": (20.0, 120.0), "rest": (0.0, 0.3)},  # Nm/rad, rad
    "torque_ripple": {"amplitude": (2.0, 8.0), "period": (0.2, 0.6)},  # Nm, rad
    "torque_sensor_ripple": {"amplitude": (2.0, 8.0), "period": (0.2, 0.6)},
}
SIGNED = {("torque_gain", "value"), ("torque_offset", "value"), ("payload", "com"), ("link_mass_scale", "value"),
          ("encoder_offset", "value"), ("base_imu_tilt", "roll"), ("base_imu_tilt", "pitch"),
          ("torque_sensor_gain", "value"), ("torque_sensor_offset", "value"), ("joint_spring", "rest")}
"""Fields whose deviation from the null value has either sign (a gain below or above 1)."""
LAG_EVERYWHERE = ("actuator_lag",)
"""Types drawn on every joint ("all": one actuator model for the robot, as the suite's lag cases)."""

P_NOMINAL = 0.15
"""Share of cases with no effect: the false-positive rate is measured on them."""
P_OUT_OF_CATALOGUE = 0.15
"""Share of cases with one effect outside the catalogue, alone."""
NOISE_SCALES = (0.0, 0.5, 1.0, 2.0)
"""Sensor noise of a case: REALISTIC_NOISE × one of these (0: noise-free logs)."""
TRAIN_MOTIONS = (2, 4)
"""Training motions per case (inclusive range); each 8–16 s; at least one gait."""
HELDOUT_MOTIONS = 2
"""Held-out motions per case (8–12 s each), none of the training motion names."""
MAX_SEED = 10**6
"""Simulation seeds drawn below this (the bench's recording seeds are 100 × seed + k)."""


class DrawError(ValueError):
    """A draw table entry that does not fit its effect's ranges, or an impossible request."""


def effect_size(effect: dict) -> float:
    """The size of an effect in its first float field's unit: |value − null| (a vec3: the norm)."""
    kind = EFFECTS[effect["type"]]
    name = next(n for n, f in kind.fields.items() if f.kind in ("float", "vec3"))
    null = np.asarray(kind.null.get(name, 0.0), float)
    return float(np.linalg.norm(np.asarray(effect[name], float) - null))


def size_unit(type_name: str) -> str:
    """The unit and field of effect_size for a type, e.g. 'value [Nm]'."""
    kind = EFFECTS[type_name]
    name, f = next((n, f) for n, f in kind.fields.items() if f.kind in ("float", "vec3"))
    return f"|{name} − null| [{f.unit or '1'}]"


def _draw_effect(rng: np.random.Generator, type_name: str, place: str | None) -> dict:
    kind = EFFECTS[type_name]
    out: dict[str, Any] = {"type": type_name}
    for name, f in kind.fields.items():
        if f.kind == "joints":
            out[name] = "all" if type_name in LAG_EVERYWHERE else place
        elif f.kind == "link":
            out[name] = place
        else:
            lo, hi = DRAW_RANGES[type_name][name]
            null = np.asarray(kind.null.get(name, 0.0), float)
            n = 3 if f.kind == "vec3" else 1
            mag = rng.uniform(lo, hi, n)
            sign = rng.choice((-1.0, 1.0), n) if (type_name, name) in SIGNED else np.ones(n)
            v = null + sign * mag
            out[name] = [float(x) for x in v] if f.kind == "vec3" else float(v[0])
    if type_name == "joint_stribeck_friction":  # breakaway is drawn as a multiple of the Coulomb level
        out["breakaway"] = out["coulomb"] * out["breakaway"]
    return out


def _places(kind_fields: dict, joints: Sequence[str], links: Sequence[str]) -> Sequence[str | None]:
    kinds = {f.kind for f in kind_fields.values()}
    return list(joints) if "joints" in kinds else list(links) if "link" in kinds else [None]


def _motions(rng: np.random.Generator, motions: Sequence[str]) -> tuple[list, list]:
    pool = [m for m in motions if m != "stand"]
    gaits = [m for m in pool if m.startswith(("walk", "trot"))]
    if len(gaits) < 1 or len(pool) < TRAIN_MOTIONS[1] + HELDOUT_MOTIONS:
        raise DrawError(f"motions: need at least one gait and {TRAIN_MOTIONS[1] + HELDOUT_MOTIONS} motions other "
                        f"than 'stand', got {list(motions)}")
    n_train = int(rng.integers(TRAIN_MOTIONS[0], TRAIN_MOTIONS[1] + 1))
    first = str(rng.choice(gaits))
    rest = [str(m) for m in rng.permutation([m for m in pool if m != first])]
    train = [first, *rest[:n_train - 1]]
    heldout = [m for m in rest[n_train - 1:] if m.startswith(("walk", "trot"))][:HELDOUT_MOTIONS]
    heldout += [m for m in rest[n_train - 1:] if m not in heldout][:HELDOUT_MOTIONS - len(heldout)]
    return ([[m, round(float(rng.uniform(8.0, 16.0)), 1)] for m in train],
            [[m, round(float(rng.uniform(8.0, 12.0)), 1)] for m in heldout])


def draw_case(seed: int, index: int, joints: Sequence[str], links: Sequence[str], motions: Sequence[str]) -> dict:
    """Case `index` of the randomised bench with master seed `seed` (depends on both only)."""
    rng = np.random.default_rng([seed, index])
    u = rng.uniform()
    if u < P_NOMINAL:
        kind, types = "nominal", []
    elif u < P_NOMINAL + P_OUT_OF_CATALOGUE:
        kind, types = "out_of_catalogue", [str(rng.choice(OUT_OF_CATALOGUE))]
    else:
        kind = "catalogue"
        n = int(rng.integers(1, 4))
        types = []
        for t in rng.permutation(CATALOGUE):
            t = str(t)
            # two frictions of one joint nest (Stribeck holds Coulomb): one friction law per case
            if "friction" in t and any("friction" in s for s in types) and t != "joint_viscous_friction":
                continue
            types.append(t)
            if len(types) == n:
                break
    effects, taken = [], set()
    for t in types:
        # one effect per place: two on one joint would be scored against each other's share
        free = [p for p in _places(EFFECTS[t].fields, joints, links) if p is None or p not in taken]
        place = free[int(rng.integers(len(free)))]
        if place is not None:
            taken.add(place)
        effects.append(_draw_effect(rng, t, place))
    scale = float(rng.choice(NOISE_SCALES))
    train, heldout = _motions(rng, motions)
    return {"seed": int(rng.integers(1, MAX_SEED)), "kind": kind, "noise_scale": scale,
            "sensor_noise": {k: v * scale for k, v in REALISTIC_NOISE.items()} if scale else {},
            "effects": effects, "train_motions": train, "heldout_motions": heldout}


def draw_cases(n: int, seed: int, joints: Sequence[str], links: Sequence[str], motions: Sequence[str]) -> list[dict]:
    """N random cases (module docstring); DrawError if the draw table does not fit the registry."""
    check_draw_ranges()
    cases = [draw_case(seed, i, joints, links, motions) for i in range(n)]
    for c in cases:
        for e in c["effects"]:
            bad = outside_range(e)
            if bad:
                raise DrawError(f"a drawn effect leaves its range: {bad}")
    return cases


def check_draw_ranges() -> None:
    """Every registered type has a draw range per float field, inside the field's simulator range
    (the null value ± the magnitude)."""
    for name, kind in EFFECTS.items():
        for field_name, f in kind.fields.items():
            if f.kind not in ("float", "vec3"):
                continue
            try:
                lo, hi = DRAW_RANGES[name][field_name]
            except KeyError:
                raise DrawError(f"effects.draws: no draw range for {name}.{field_name}") from None
            null = float(np.max(np.atleast_1d(kind.null.get(field_name, 0.0))))
            signed = (name, field_name) in SIGNED
            ends = (null - hi, null + hi) if signed else (null + lo, null + hi)
            if name == "joint_stribeck_friction" and field_name == "breakaway":
                ends = (DRAW_RANGES[name]["coulomb"][0] * lo, DRAW_RANGES[name]["coulomb"][1] * hi)
            if not (0 <= lo <= hi) or ends[0] < f.lo or ends[1] > f.hi:
                raise DrawError(f"effects.draws: {name}.{field_name} draws {ends}, outside [{f.lo}, {f.hi}]")
