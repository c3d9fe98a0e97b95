"""Jerk-limited, time-synchronised timing of a collision-free path with Ruckig (DESIGN §4 "Motion", §6).

Open-source Ruckig plans one state-to-state motion at a time, so the trajectory is a chain of pieces:

* Each keyframe segment is first timed as **one** Ruckig motion from keyframe to keyframe (all 21 joints
  time-synchronised, ``Synchronization.Time``), passing each keyframe with the spline's velocity (zero where the
  artist holds, at home and at the end) and zero acceleration, stretched to the keyframe times with
  ``minimum_duration``.
* The motion is sampled at ``check_factor`` × the show rate and collision-checked. Where it collides, the corners
  of the repaired path (``studio.motion.path``: points joined by collision-checked straight lines) become
  **via-points**:
  the segment is re-timed through them, each via passed with the velocity of a clamped cubic spline through the
  segment's states, the durations split in proportion to the path's nominal times but never below each piece's
  shortest feasible time. A piece that still collides (or swings out of a joint's limits) becomes rest-to-rest and
  phase-synchronised: the straight, checked line between its corners (split at a path point if needed).
* A segment too slow for its time with its keyframes passed at the spline's velocities passes its end keyframe at
  rest instead, or both (the one before is then re-timed to end at rest), when that fits: the keyframe boxes of
  :mod:`studio.motion.reach` give each move its rest-to-rest time, and a keyframe velocity that heads away from the
  next keyframe can cost more time than it saves.
* A segment whose straight move collided and that would still be late through the path's corners (or that
  collides even along them) tries one via-point near the straight move (:mod:`studio.motion.via_search`): the
  corners follow the spline and the repair walk, not the clock, and can cost the move twice its straight time.
* Two adjacent path points whose motion collides at the trajectory's checks (a thin collision the path's 2° check
  stepped over) get one more point beside the contact (:mod:`studio.motion.sidestep`), passed at rest.
* A segment whose shortest feasible time exceeds its requested time raises ``SegmentTooFastError`` with every
  such segment and its feasible time; with ``allow_late`` the segment is stretched and later keyframes shift
  (reported in the result, never silent).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np

from studio.errors import ProgressFn, report
from studio.motion.errors import PathError, SegmentTiming, SegmentTooFastError, check_cancel
from studio.motion.limits import JointLimits
from studio.motion.path import Path
from studio.motion.segment_timer import Piece, RuckigSolver, SegmentTimer, colliding, evaluate, overshoots
from studio.motion.sidestep import SidestepConfig, insert_point, sidestep
from studio.motion.via_search import ViaSearch, via_detour
from studio.sim.physics import CollisionWorld


@dataclass(frozen=True)
class TimingConfig:
    """Timing and checking options."""

    rate_hz: float = 40.0  # show sample rate (the controller's 40 Hz)
    check_factor: int = 4  # collision checks at this multiple of rate_hz (issue: 4×)
    velocity_margin: float = 0.95  # keyframe/via velocities are clipped to this fraction of the velocity limit
    max_rounds: int = 40  # via-insertion rounds per segment before giving up
    allow_late: bool = False  # stretch too-fast segments (shifting later keyframes) instead of raising
    via: ViaSearch = field(default_factory=ViaSearch)  # one via-point near a colliding straight move, before late
    sidestep: SidestepConfig = field(default_factory=SidestepConfig)  # a point beside a thin collision, not a failure


@dataclass
class TimedTrajectory:
    """The chained pieces; ``key_times (K,)`` and ``key_poses (K, 21)`` are hit exactly."""

    pieces: list[Piece]
    key_times: np.ndarray
    key_poses: np.ndarray
    late: list[SegmentTiming] = field(default_factory=list)  # segments stretched under allow_late
    collision_checks: int = 0  # poses checked along the timed trajectory

    @property
    def duration(self) -> float:
        return float(self.key_times[-1])

    def state(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Position, velocity, acceleration ``(T, 21)`` at show times ``t (T,)`` (clamped to the show).

        A trajectory of one keyframe (no pieces, duration 0) holds that pose at rest."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), 0.0, self.duration)
        if not self.pieces:
            hold = np.repeat(self.key_poses[:1], len(t), axis=0)
            return hold, np.zeros_like(hold), np.zeros_like(hold)
        out = evaluate(self.pieces, t)
        hit = np.isin(t, self.key_times)  # keyframes exactly (Ruckig's end state is within ~1e-15 rad)
        out[0, hit] = self.key_poses[np.searchsorted(self.key_times, t[hit])]
        return out[0], out[1], out[2]

    def max_jerk_ratio(self, jerk_limit: np.ndarray) -> float:
        """Largest |jerk| any piece uses, divided by that joint's jerk limit."""
        worst = 0.0
        for p in self.pieces:
            for d, prof in enumerate(p.traj.profiles[0]):
                worst = max(worst, float(np.abs(prof.j).max()) / float(jerk_limit[d]))
        return worst


def _ends_at_rest(timer, t0: float, span: float, tau, q, v0, v1, at_rest) -> tuple[bool, bool] | None:
    """For a segment too slow for its ``span`` s with its keyframes passed at the spline's velocities: which of its
    ends (start, end) to pass at rest instead so that it fits, the end alone first (nothing before it is re-timed),
    then both; None when neither fits, or both ends already rest (the reach of :mod:`studio.motion.reach` is rest to
    rest: a via velocity that heads away from the next keyframe can cost more than it gives)."""
    for start, end in ((False, True), (True, True)):
        trial = at_rest.copy()
        trial[0] |= start
        trial[-1] |= end
        if (trial == at_rest).all():
            continue
        v = timer.via_velocities(tau, q, v0 * (not trial[0]), v1 * (not trial[-1]), trial)
        if timer.time(t0, t0 + span, tau, q, v, trial)[0] is not None:
            return bool(trial[0] and not at_rest[0]), bool(trial[-1] and not at_rest[-1])
    return None


def _via_detour(path, s, kv, t0: float, span: float, timer, world, rate: float, cfg: TimingConfig, cancel=None):
    """:func:`~studio.motion.via_search.via_detour` for segment ``s``: its pieces or None, and the poses checked."""
    a, b = path.key_index[s], path.key_index[s + 1]
    ends, velocities = (path.poses[a], path.poses[b]), (kv[s], kv[s + 1])
    return via_detour(timer, world, t0, span, ends, velocities, rate, s, cfg.via, cancel)


def _sidestep_thin(path, thin: dict, idx: list, added: list, stop: set, world, cfg: TimingConfig, cancel=None):
    """A point beside each thin collision ``thin``: {path index lo: (its piece's start s, a colliding pose or
    None)}, the move lo → lo + 1 colliding. Each point is inserted after lo (:func:`~studio.motion.sidestep.
    insert_point`) and passed at rest. Returns ``idx``, ``added`` and ``stop`` renumbered, the new points added, and
    the poses checked; raises ``PathError`` where no point is found."""
    checks = 0
    for lo in sorted(thin, reverse=True):  # from the end, so the indices still to do stay valid
        piece_t0, near = thin[lo]
        ends = path.poses[lo], path.poses[lo + 1]
        m, n = (None, 0) if near is None else sidestep(world, *ends, near, cfg.sidestep, cancel)
        checks += n
        if m is None:
            raise PathError(
                f"the motion near t = {piece_t0:.3f} s collides even along the repaired path; "
                "move the neighbouring keyframes apart or add a keyframe in between"
            )
        insert_point(path, lo, m)
        idx, added = [i + (i > lo) for i in idx], [i + (i > lo) for i in added] + [lo + 1]
        stop = {i + (i > lo) for i in stop}
    return idx, added, stop, checks


def _time_segment(path, s, kv, duration, req_t, slow, timer, world, rate, cfg, cancel=None):
    """Rounds of timing + checking for segment ``s``; returns (pieces, restart previous?, checks).

    Round 1 times keyframe to keyframe directly; when that collides, the segment's path corners become via-points
    (passed with spline velocities); pieces that still collide, or swing out of a joint's limits, are made
    rest-to-rest at both ends, which makes them the straight, collision-checked line between two corners.
    """
    a, b = path.key_index[s], path.key_index[s + 1]
    t0 = float(np.sum(duration[:s]))
    idx, stop, checks, collided, searched = [a, b], set(), 0, False, None  # searched: the span a via was sought in

    def via_near_the_straight_move():  # the via search over the segment's current span (recorded in ``searched``)
        nonlocal checks, searched
        searched = float(duration[s])
        via, n = _via_detour(path, s, kv, t0, searched, timer, world, rate, cfg, cancel)
        checks += n
        return via

    for _ in range(cfg.max_rounds):
        check_cancel(cancel)
        tau, q = path.times[idx], path.poses[idx]
        at_rest = np.array([i in stop or (i == a and not kv[s].any()) or (i == b and not kv[s + 1].any()) for i in idx])
        v = timer.via_velocities(tau, q, kv[s], kv[s + 1], at_rest)
        got, feasible = timer.time(t0, t0 + duration[s], tau, q, v, at_rest)
        if got is None:
            ends = _ends_at_rest(timer, t0, float(duration[s]), tau, q, kv[s], kv[s + 1], at_rest)
            if ends is not None:  # passing a keyframe at rest makes the segment fit its time: before stretching it
                if ends[1]:
                    kv[s + 1] = 0.0
                if ends[0]:
                    kv[s] = 0.0
                    if s > 0:
                        return None, True, checks
                continue
            if collided and searched is None and (via := via_near_the_straight_move()) is not None:
                return via, False, checks  # the straight move collided: one via-point near it, before stretching
            slow[s] = SegmentTiming(s, float(req_t[s]), float(req_t[s + 1]), feasible)
            duration[s] = feasible  # stretched: reported unless allow_late
            continue
        check_cancel(cancel)
        t, bad = colliding(world, got, t0, t0 + duration[s], rate)
        checks += len(t)
        over = [k for k, p in enumerate(got) if overshoots(p.traj, timer.limits)]  # a time-filling swing
        if not bad.any() and not over:
            return got, False, checks
        collided |= len(idx) == 2 and bool(bad.any())
        if len(idx) == 2 and not at_rest.all() and bad.any():
            idx = [int(i) for i in np.flatnonzero(path.corner[a : b + 1]) + a]
            if len(idx) > 2:
                continue
        starts = np.array([p.t0 for p in got])
        added, thin = [], {}
        hit = np.clip(np.searchsorted(starts, t[bad], side="right") - 1, 0, len(got) - 1)
        for k in np.union1d(hit, over).astype(int):
            if at_rest[k] and at_rest[k + 1]:  # missed between the path check's samples: split at a path point
                if idx[k + 1] - idx[k] < 2:  # adjacent points: a thin collision the path's check stepped over
                    if searched != float(duration[s]) and (via := via_near_the_straight_move()) is not None:
                        return via, False, checks  # the repaired path is no way through: one via, if any
                    mine = bad & (t >= got[k].t0) & (t <= got[k].t0 + got[k].traj.duration)
                    thin[idx[k]] = (got[k].t0, evaluate(got, t[mine][:1])[0][0] if mine.any() else None)
                    continue
                added.append((idx[k] + idx[k + 1]) // 2)
                continue
            stop |= {idx[k], idx[k + 1]}  # rest to rest between corners: the straight, checked line
            if idx[k + 1] == b:
                kv[s + 1] = 0.0
            if idx[k] == a and kv[s].any():
                kv[s] = 0.0
                if s > 0:
                    return None, True, checks
        if thin:
            idx, added, stop, n = _sidestep_thin(path, thin, idx, added, stop, world, cfg, cancel)
            checks += n
            b = path.key_index[s + 1]
        stop |= set(added)
        idx = sorted(set(idx) | set(added))
    raise PathError(f"segment {s} ({req_t[s]:.3f} s → {req_t[s + 1]:.3f} s) stays in collision after re-timing")


def time_path(
    path: Path, key_velocity: np.ndarray, limits: JointLimits, world: CollisionWorld, cfg: TimingConfig | None = None,
    progress: ProgressFn | None = None, cancel: threading.Event | None = None,
) -> TimedTrajectory:  # fmt: skip
    """Time ``path`` through its keyframes (``key_velocity (K, 21)`` rad/s at each) into a checked trajectory.

    Stage "timing": step ``s + 1`` of ``K − 1`` once segment ``s`` is timed and collision-checked along the
    trajectory (a step back when a keyframe must be re-timed at rest). Raises ``SegmentTooFastError`` (every segment
    that cannot meet its time, with its feasible time) unless ``cfg.allow_late``, ``PathError`` when a segment cannot
    be made collision-free, and :class:`~studio.motion.errors.PlanCancelled` within a timing round of ``cancel``
    being set.
    """
    cfg = cfg or TimingConfig()
    timer = SegmentTimer(RuckigSolver(limits), limits, cfg.velocity_margin)
    rate = cfg.rate_hz * cfg.check_factor
    ki = path.key_index
    req_t = path.times[ki]
    kv = timer.inward(path.poses[ki], np.array(key_velocity, dtype=float))
    duration = np.diff(req_t)  # per segment; grows only where a segment is stretched
    slow: dict[int, SegmentTiming] = {}
    pieces: list[list[Piece]] = [[] for _ in duration]
    checks, s = 0, 0
    while s < len(duration):
        got, restart, n = _time_segment(path, s, kv, duration, req_t, slow, timer, world, rate, cfg, cancel)
        checks += n
        if restart:  # keyframe s must now be passed at rest: re-time the segment before it
            s -= 1
            report(progress, "timing", s, len(duration))
            continue
        pieces[s] = got
        s += 1
        report(progress, "timing", s, len(duration))
    late = [slow[k] for k in sorted(slow)]
    if late and not cfg.allow_late:
        raise SegmentTooFastError(late)
    key_t = np.concatenate([[0.0], np.cumsum(duration)])
    return TimedTrajectory(
        [p for seg in pieces for p in seg], key_t, path.poses[path.key_index], late, checks + path.collision_checks
    )
