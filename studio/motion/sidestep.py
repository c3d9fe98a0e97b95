"""A point beside a thin collision that the path's check stepped over (DESIGN §4 "Motion").

The path joins its points by straight motions checked every ``PathConfig.check_step_deg`` (2°); the timed
trajectory is checked at 4 × 40 Hz, on other poses. A grazing contact narrower than the path's step can lie between
the path's samples and under the trajectory's. Measured on ``benchmarks/bench_crossing.py`` (seed 2, factor 1.02):
the ring finger's tip 6.5 µm into the pinky, over 0.7° of a 13.6° move. The timing then splits the move at every
path point and is left with two adjacent points whose motion collides. Instead of failing there, it asks
:func:`sidestep` for one more point near the contact and passes it at rest; :func:`insert_point` adds it to the path.

:func:`sidestep` draws points around the colliding pose (normal, deviation ``spreads`` in turn, the smallest
first) and keeps the first that is collision-free with both straight halves, a → point and point → b, free when
checked every ``fine_deg`` (the path's 2° / 8). Seeded, so plans stay reproducible.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from studio.motion.errors import check_cancel
from studio.motion.path import Path
from studio.sim.physics import CollisionWorld


@dataclass(frozen=True)
class SidestepConfig:
    """Where to look for a point beside a thin collision."""

    tries: int = 120  # points drawn in all, split evenly over the spreads (0: never sidestep) [0, 100000]
    spreads: tuple[float, ...] = (0.01, 0.03, 0.1)  # std, rad, of the draws around the contact, smallest first
    fine_deg: float = 0.25  # the halves' straight motions are checked at this spacing, degrees (0, 2]
    seed: int = 0  # random seed of the draws [0, 4294967295]

    def __post_init__(self) -> None:
        if self.tries < 0 or not 0 < self.fine_deg <= 2 or not self.spreads or min(self.spreads) <= 0:
            raise ValueError(
                "a sidestep needs tries ≥ 0, a check spacing in (0, 2] degrees and positive spreads, got "
                f"tries={self.tries}, fine_deg={self.fine_deg}, spreads={self.spreads}"
            )


def _line(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """Poses on the straight motion a → b every ``step`` rad (max-norm) or closer, b included, a not: ``(n, 21)``."""
    n = max(1, int(np.ceil(np.abs(b - a).max() / step)))
    return a + np.linspace(0.0, 1.0, n + 1)[1:, None] * (b - a)


def sidestep(
    world: CollisionWorld, a: np.ndarray, b: np.ndarray, near: np.ndarray, cfg: SidestepConfig,
    cancel: threading.Event | None = None,
) -> tuple[np.ndarray | None, int]:  # fmt: skip
    """A pose ``(21,)`` rad near ``near`` (a colliding pose of the motion a → b) that is collision-free, with a → it
    and it → b free when checked every ``cfg.fine_deg``; None when no draw is. Also the poses checked."""
    rng = np.random.default_rng(cfg.seed)
    lower, upper, step = world.hand.lower, world.hand.upper, np.radians(cfg.fine_deg)
    checks = 0
    per = cfg.tries // len(cfg.spreads) if cfg.tries else 0
    for spread in sorted(cfg.spreads):
        if per == 0:
            break
        check_cancel(cancel)
        cand = np.clip(near + rng.normal(0.0, spread, (per, len(near))), lower, upper)
        checks += len(cand)
        free = cand[~world.in_collision(cand, check=False)]
        for m in free[np.argsort(np.abs(free - near).max(axis=1))]:  # the closest to the contact first
            check_cancel(cancel)
            halves = np.concatenate([_line(a, m, step), _line(m, b, step)])
            checks += len(halves)
            if not world.in_collision(halves, check=False).any():
                return m, checks
    return None, checks


def insert_point(path: Path, after: int, pose: np.ndarray) -> None:
    """Insert ``pose`` between path points ``after`` and ``after + 1``, halfway in nominal time, as a repaired
    corner; the keyframe indices after it move up by one. Changes ``path`` in place."""
    t = 0.5 * (path.times[after] + path.times[after + 1])
    at = after + 1
    path.times = np.insert(path.times, at, t)
    path.poses = np.insert(path.poses, at, pose, axis=0)
    path.repaired = np.insert(path.repaired, at, True)
    path.refined = np.insert(path.refined, at, False)
    path.corner = np.insert(path.corner, at, True)
    path.key_index = np.where(path.key_index >= at, path.key_index + 1, path.key_index)
