"""Per-joint motion limits (position, velocity, acceleration, jerk) shared by the planner and the show file.

Defaults come from the LX-15D bus servo: its datasheet gives 0.16 s/60° (7.4 V) to 0.20 s/60° (6 V) with no load,
i.e. 5.2–6.5 rad/s; the URDF stores 5.2 rad/s and is the one source of that number (``hardware.safety`` reads it
too). Under the load of a finger (and the whole hand for the wrist) a servo is slower, so the planner uses a fraction
of the URDF speed, and acceleration and jerk values that reach that speed in about a quarter of a second without a
visible kick. Every other number is a field of :class:`LimitsConfig`, stated nowhere else.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from studio.sim.hand import Hand


@dataclass(frozen=True)
class LimitsConfig:
    """How the per-joint velocity, acceleration and jerk limits are derived from the hand."""

    # bounds: below 0.01 a move of one radian outlasts what Ruckig can time (hours); far above what a servo does
    velocity_scale: float = 0.75  # fraction of the URDF velocity limit (LX-15D no-load 5.2 rad/s → 3.9 rad/s) [0.01, 1]
    acceleration: float = 20.0  # rad/s²; 3.9 rad/s is reached in ~0.2 s [0.01, 10000]
    jerk: float = 200.0  # rad/s³; acceleration ramps up in 0.1 s [0.01, 1000000]
    wrist_scale: float = 0.5  # the wrist turns the whole hand: its velocity/acceleration/jerk are scaled by this (0, 1]
    overrides: dict[str, tuple[float, float, float]] = field(default_factory=dict)  # joint → (vel, acc, jerk)


@dataclass(frozen=True)
class JointLimits:
    """Limits of every joint, each (21,) in the hand's joint order."""

    lower: np.ndarray  # (21,) rad
    upper: np.ndarray  # (21,) rad
    velocity: np.ndarray  # (21,) rad/s, > 0
    acceleration: np.ndarray  # (21,) rad/s², > 0
    jerk: np.ndarray  # (21,) rad/s³, > 0

    @classmethod
    def from_hand(cls, hand: Hand, cfg: LimitsConfig | None = None) -> JointLimits:
        """Limits for ``hand`` following ``cfg`` (defaults: LX-15D-derived, see the module docstring)."""
        cfg = cfg or LimitsConfig()
        unknown = sorted(set(cfg.overrides) - set(hand.joint_names))
        if unknown:
            raise ValueError(f"limit overrides name unknown joints {unknown}; use the hand's joint names")
        missing = [j.name for j in hand.joints if not j.velocity > 0]
        if missing:
            raise ValueError(f"the hand's URDF gives no velocity limit for {missing}: set <limit velocity=...> (rad/s)")
        vel, acc, jerk = [], [], []
        for j in hand.joints:
            scale = cfg.wrist_scale if j.name == "wrist" else 1.0
            v = j.velocity * cfg.velocity_scale * scale
            a, k = cfg.acceleration * scale, cfg.jerk * scale
            v, a, k = cfg.overrides.get(j.name, (v, a, k))
            vel.append(v)
            acc.append(a)
            jerk.append(k)
        out = cls(hand.lower, hand.upper, np.array(vel), np.array(acc), np.array(jerk))
        out.check()
        return out

    def check(self) -> None:
        """Raise ``ValueError`` unless every array is (D,), finite, lower ≤ upper and vel/acc/jerk > 0."""
        problems = limit_problems(self.as_dict())
        if problems:
            raise ValueError("; ".join(problems))

    def as_dict(self) -> dict[str, list[float]]:
        return {k: np.asarray(getattr(self, k), dtype=float).tolist() for k in LIMIT_KEYS}

    @classmethod
    def from_dict(cls, d: dict[str, list[float]]) -> JointLimits:
        return cls(**{k: np.asarray(d[k], dtype=float) for k in LIMIT_KEYS})

    def equals(self, other: JointLimits) -> bool:
        return all(np.array_equal(getattr(self, k), getattr(other, k)) for k in LIMIT_KEYS)


LIMIT_KEYS = ("lower", "upper", "velocity", "acceleration", "jerk")


def limit_problems(d: dict[str, list[float]], names: list[str] | None = None) -> list[str]:
    """Human-readable problems of a limits table (empty when sound)."""
    problems = []
    arrays = {k: np.asarray(d.get(k, []), dtype=float) for k in LIMIT_KEYS}
    n = len(names) if names is not None else len(arrays["lower"])
    for k, a in arrays.items():
        if a.shape != (n,):
            problems.append(f"limits.{k} has {a.size} values; expected one per joint ({n})")
        elif not np.isfinite(a).all():
            problems.append(f"limits.{k} contains NaN/inf")
        elif k in ("velocity", "acceleration", "jerk") and (a <= 0).any():
            problems.append(f"limits.{k} must be > 0 for every joint")
    if not problems and (arrays["lower"] > arrays["upper"]).any():
        problems.append("limits.lower exceeds limits.upper for some joint")
    return problems
