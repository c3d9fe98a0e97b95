"""A quicker way round a collision: one via-point near the straight move, for a segment that would be late.

The keyframe boxes of :mod:`studio.motion.reach` give each move between keyframes its straight rest-to-rest time.
Where the straight move collides (two fingers crossing as they curl), the timing threads the corners of the
repaired path (:mod:`studio.motion.path`), and those follow the keyframe spline and the repair walk, not the
clock: a corner just before the keyframe, where the direction turns, can cost the move 40 % more than the
straight one, and the segment is late although a free move within its time exists.

:func:`via_detour` looks for that move: ``tries`` random via-points ``m = q_a + s (q_b − q_a) + ε`` (``s`` uniform
in [0.2, 0.8], ``ε`` normal with a deviation of ``spread`` rad drawn per point from ``spreads``: small ones keep
close to the straight line, large ones let a finger wait or swing round its neighbour), each collision-free, passed
with the via spline's velocity, half of it or at rest. Every candidate is timed with Ruckig (cheap), then the
fastest that fit the segment's time are timed to exactly that time and collision-checked along the trajectory,
fastest first; the first free one is the segment's motion. Random, with the plan's seed: plans stay reproducible.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np

from studio.motion.errors import PlanError, check_cancel
from studio.motion.segment_timer import Piece, SegmentTimer, colliding, overshoots
from studio.sim.physics import CollisionWorld

VIA_SCALES = (1.0, 0.5, 0.0)  # the via is passed at these fractions of the via spline's velocity (0: at rest)


@dataclass(frozen=True)
class ViaSearch:
    """What :func:`via_detour` tries."""

    tries: int = 400  # random via-points drawn for a segment [0, 100000]
    spreads: tuple[float, ...] = (0.1, 0.2, 0.4)  # deviations (rad) of the random offset from the straight move
    checked: int = 100  # at most this many of the fastest fitting candidates are collision-checked along the motion
    seed: int = 0  # random seed (with the segment's number: plans are reproducible) [0, 4294967295]

    def __post_init__(self) -> None:
        if self.tries < 0 or self.checked < 0 or not self.spreads or min(self.spreads) <= 0:
            raise ValueError(f"the via search needs tries ≥ 0, checked ≥ 0 and deviations > 0, not {self}")


def via_detour(
    timer: SegmentTimer,
    world: CollisionWorld,
    t0: float,
    span: float,
    ends: tuple[np.ndarray, np.ndarray],
    velocities: tuple[np.ndarray, np.ndarray],
    rate: float,
    segment: int = 0,
    cfg: ViaSearch | None = None,
    cancel: threading.Event | None = None,
) -> tuple[list[Piece] | None, int]:
    """Pieces from keyframe ``ends[0]`` to ``ends[1]`` ``(21,)`` rad, leaving and reaching them at ``velocities``
    ``(21,)`` rad/s, in exactly ``span`` s from show time ``t0`` through one via-point, within the joint limits and
    collision-free at ``rate`` Hz along the trajectory; None when no candidate fits (module doc). ``segment`` seeds
    the draw with ``cfg.seed``. Returns the pieces and the poses checked; raises
    :class:`~studio.motion.errors.PlanCancelled` within one candidate of ``cancel`` being set."""
    cfg = cfg or ViaSearch()
    if cfg.tries <= 0:
        return None, 0
    rng = np.random.default_rng((cfg.seed, segment))
    qa, qb = (np.asarray(e, dtype=np.float64) for e in ends)
    va, vb = velocities
    hand = world.hand
    s = rng.uniform(0.2, 0.8, (cfg.tries, 1))
    spread = rng.choice(np.asarray(cfg.spreads, dtype=np.float64), (cfg.tries, 1))
    vias = np.clip(qa + s * (qb - qa) + rng.normal(0.0, 1.0, (cfg.tries, len(qa))) * spread, hand.lower, hand.upper)
    checks = len(vias)
    free = ~world.in_collision(vias, check=False)
    options = []  # (feasible s, tau, q, v, stop)
    for m in vias[free]:
        check_cancel(cancel)
        da, db = np.abs(m - qa).max(), np.abs(qb - m).max()
        tau = np.array([t0, t0 + span * da / max(da + db, 1e-12), t0 + span])
        q = np.array([qa, m, qb])
        spline_v = timer.via_velocities(tau, q, va, vb, np.array([not va.any(), False, not vb.any()]))
        for scale in VIA_SCALES:  # the via spline's velocity at the via, scaled (0: at rest)
            stop = np.array([not va.any(), scale == 0.0, not vb.any()])
            v = spline_v.copy()
            v[1] *= scale
            try:
                feasible = float(timer.shortest(tau, q, v, stop).sum())
            except PlanError:  # no motion within the limits reaches this state
                continue
            if feasible <= span + 1e-9:
                options.append((feasible, tau, q, v, stop))
    options.sort(key=lambda o: o[0])
    for _, tau, q, v, stop in options[: cfg.checked]:
        check_cancel(cancel)
        try:
            pieces, _ = timer.time(t0, t0 + span, tau, q, v, stop)
        except PlanError:  # Ruckig cannot stretch this one to the span
            continue
        if pieces is None or any(overshoots(p.traj, timer.limits) for p in pieces):
            continue
        bad = colliding(world, pieces, t0, t0 + span, rate)[1]
        checks += len(bad)
        if not bad.any():
            return pieces, checks
    return None, checks
