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
* A segment whose shortest feasible time exceeds its requested time raises ``SegmentTooFastError`` with every
  such segment and its feasible time; with ``allow_late`` the segment is stretched and later keyframes shift
  (reported in the result, never silent).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Synchronization, Trajectory
from scipy.interpolate import CubicSpline

from studio.motion.errors import PathError, PlanError, SegmentTiming, SegmentTooFastError, check_cancel
from studio.motion.limits import JointLimits
from studio.motion.path import Path
from studio.progress import ProgressFn, report
from studio.sim.physics import CollisionWorld


@dataclass(frozen=True)
class TimingConfig:
    """Timing and checking options."""

    rate_hz: float = 40.0  # show sample rate (the controller's 40 Hz)
    check_factor: int = 4  # collision checks at this multiple of rate_hz (issue: 4×)
    velocity_margin: float = 0.95  # keyframe/via velocities are clipped to this fraction of the velocity limit
    max_rounds: int = 40  # via-insertion rounds per segment before giving up
    allow_late: bool = False  # stretch too-fast segments (shifting later keyframes) instead of raising


@dataclass
class Piece:
    """One Ruckig motion starting at ``t0`` (s, show time)."""

    t0: float
    traj: Trajectory

    @property
    def duration(self) -> float:
        return float(self.traj.duration)


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


def evaluate(pieces: list[Piece], t: np.ndarray) -> np.ndarray:
    """Position, velocity, acceleration ``(3, T, 21)`` of chained ``pieces`` at show times ``t (T,)``."""
    starts = np.array([p.t0 for p in pieces])
    idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(pieces) - 1)
    out = np.empty((3, len(t), pieces[0].traj.degrees_of_freedom))
    for n, (ti, k) in enumerate(zip(t, idx)):
        piece = pieces[k]
        out[:, n] = piece.traj.at_time(min(max(ti - piece.t0, 0.0), piece.duration))
    return out


class _Solver:
    """Ruckig calls with the joint limits set once."""

    def __init__(self, limits: JointLimits):
        self.dof = len(limits.velocity)
        self.ruckig = Ruckig(self.dof)
        self.inp = InputParameter(self.dof)
        self.inp.max_velocity = limits.velocity.tolist()
        self.inp.max_acceleration = limits.acceleration.tolist()
        self.inp.max_jerk = limits.jerk.tolist()
        self.inp.min_position = limits.lower.tolist()
        self.inp.max_position = limits.upper.tolist()

    def solve(self, p0, v0, p1, v1, duration: float | None, straight: bool = False) -> Trajectory | None:
        """One motion (p0, v0, 0) → (p1, v1, 0); None when Ruckig finds none within the limits."""
        inp, zero = self.inp, [0.0] * self.dof
        inp.current_position, inp.current_velocity, inp.current_acceleration = list(p0), list(v0), zero
        inp.target_position, inp.target_velocity, inp.target_acceleration = list(p1), list(v1), zero
        inp.synchronization = Synchronization.Phase if straight else Synchronization.Time
        inp.minimum_duration = duration
        traj = Trajectory(self.dof)
        try:
            res = self.ruckig.calculate(inp, traj)
        except ValueError:  # a code the binding's Result lacks: -101, the motion outlasts what Ruckig computes
            return None
        return traj if res in (Result.Working, Result.Finished) else None


def _allocate(minimum: np.ndarray, weight: np.ndarray, total: float) -> np.ndarray:
    """Durations ``d = max(minimum, c·weight)`` summing to ``total`` (requires Σ minimum ≤ total)."""
    lo, hi = 0.0, total / max(weight.min(), 1e-12)
    for _ in range(100):
        c = (lo + hi) / 2
        lo, hi = (c, hi) if np.maximum(minimum, c * weight).sum() < total else (lo, c)
    d = np.maximum(minimum, hi * weight)
    free = d > minimum
    if free.any():  # put the rounding remainder on the stretchable pieces
        d[free] += (total - d.sum()) * weight[free] / weight[free].sum()
    return d


def via_spline_velocities(tau: np.ndarray, q: np.ndarray, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """Velocities ``(n, 21)`` rad/s at a segment's states ``q (n, 21)`` at times ``tau (n,)``: a cubic spline through
    them clamped to the end velocities ``v0``/``v1`` (21,). This via-point spline is not the keyframe spline
    (``studio.motion.path.keyframe_spline``): it threads via-points between two keyframes whose velocities that
    spline has already fixed."""
    v = np.zeros_like(q)
    v[0], v[-1] = v0, v1
    if len(q) > 2:
        v[1:-1] = CubicSpline(tau, q, bc_type=((1, v0), (1, v1)), axis=0)(tau[1:-1], 1)
    return v


class SegmentTimer:
    """Times one keyframe segment through a chosen set of via-points of the path."""

    def __init__(self, solver: _Solver, limits: JointLimits, cfg: TimingConfig):
        self.solver, self.limits, self.cfg = solver, limits, cfg

    def via_velocities(self, tau: np.ndarray, q: np.ndarray, v0: np.ndarray, v1: np.ndarray, stop: np.ndarray):
        """Velocities (n, 21) at the states ``q (n, 21)``: the via spline's, within the limits, zero where ``stop``."""
        v = via_spline_velocities(tau, q, v0, v1)
        vmax = self.cfg.velocity_margin * self.limits.velocity
        v = self.inward(q, np.clip(v, -vmax, vmax))
        v[stop] = 0.0
        return v

    def inward(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Zero each velocity component that heads out through a joint limit closer than its braking distance
        (v²/2a + |v|·a/j, a jerk-limited stop), so no piece overshoots a limit."""
        lim = self.limits
        brake = v**2 / (2 * lim.acceleration) + np.abs(v) * lim.acceleration / lim.jerk
        out = ((v < 0) & (q - brake <= lim.lower)) | ((v > 0) & (q + brake >= lim.upper))
        return np.where(out, 0.0, v)

    def time(self, t0: float, t1: float, tau, q, v, stop) -> tuple[list[Piece] | None, float]:
        """Pieces from t0 to t1 through states (q, v); (None, feasible) when Σ shortest times > t1 − t0."""
        n = len(q) - 1
        straight = stop[:-1] & stop[1:]
        minimum = np.empty(n)
        for k in range(n):
            tr = self.solver.solve(q[k], v[k], q[k + 1], v[k + 1], None, bool(straight[k]))
            if tr is None:
                raise PlanError(
                    f"no motion reaches the path state near t = {tau[k]:.3f} s within the limits: the velocity, "
                    "acceleration or jerk limits are too small to reach it (a motion of hours), or the state lies "
                    "outside a joint's range; raise the limits"
                )
            minimum[k] = tr.duration
        total = t1 - t0
        for _ in range(10):
            if minimum.sum() > total + 1e-9:
                return None, float(minimum.sum())
            d = _allocate(minimum, np.maximum(np.diff(tau), 1e-6), total)
            pieces, start = [], t0
            for k in range(n):
                tr = self.solver.solve(q[k], v[k], q[k + 1], v[k + 1], float(d[k]), bool(straight[k]))
                if tr is None or tr.duration > d[k] + 1e-9:  # a blocked interval: that duration is impossible
                    minimum[k] = d[k] + 1e-3 if tr is None else tr.duration
                    break
                pieces.append(Piece(start, tr))
                start += d[k]
            else:
                return pieces, float(minimum.sum())
        raise PlanError(f"could not fit the motion between t = {t0:.3f} s and t = {t1:.3f} s to its duration")


def _overshoots(traj: Trajectory, limits: JointLimits, tol: float = 1e-9) -> bool:
    """True when the piece leaves a joint's position limits (Ruckig may swing out to fill a long duration)."""
    ext = traj.position_extrema
    lo = np.array([e.min for e in ext])
    hi = np.array([e.max for e in ext])
    return bool((lo < limits.lower - tol).any() or (hi > limits.upper + tol).any())


def _colliding(world: CollisionWorld, pieces: list[Piece], t0: float, t1: float, rate: float):
    """Check-grid times ``(T,)`` in [t0, t1] (ends included) and their penetration flags ``(T,)``."""
    grid = np.arange(np.ceil(t0 * rate), np.floor(t1 * rate) + 1) / rate
    t = np.unique(np.concatenate([[t0], grid[(grid >= t0) & (grid <= t1)], [t1]]))
    pos = np.clip(evaluate(pieces, t)[0], world.hand.lower, world.hand.upper)
    return t, world.in_collision(pos, check=False)


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


def _time_segment(path, s, kv, duration, req_t, slow, timer, world, rate, cfg, cancel=None):
    """Rounds of timing + checking for segment ``s``; returns (pieces, restart previous?, checks).

    Round 1 times keyframe to keyframe directly; when that collides, the segment's path corners become via-points
    (passed with spline velocities); pieces that still collide, or swing out of a joint's limits, are made
    rest-to-rest at both ends, which makes them the straight, collision-checked line between two corners.
    """
    a, b = path.key_index[s], path.key_index[s + 1]
    t0 = float(np.sum(duration[:s]))
    idx, stop, checks = [a, b], set(), 0
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
            slow[s] = SegmentTiming(s, float(req_t[s]), float(req_t[s + 1]), feasible)
            duration[s] = feasible  # stretched: reported unless allow_late
            continue
        check_cancel(cancel)
        t, bad = _colliding(world, got, t0, t0 + duration[s], rate)
        checks += len(t)
        over = [k for k, p in enumerate(got) if _overshoots(p.traj, timer.limits)]  # a time-filling swing
        if not bad.any() and not over:
            return got, False, checks
        if len(idx) == 2 and not at_rest.all() and bad.any():
            idx = [int(i) for i in np.flatnonzero(path.corner[a : b + 1]) + a]
            if len(idx) > 2:
                continue
        starts = np.array([p.t0 for p in got])
        added = []
        hit = np.clip(np.searchsorted(starts, t[bad], side="right") - 1, 0, len(got) - 1)
        for k in np.union1d(hit, over).astype(int):
            if at_rest[k] and at_rest[k + 1]:  # missed between the path check's samples: split at a path point
                if idx[k + 1] - idx[k] < 2:
                    raise PathError(
                        f"the motion near t = {got[k].t0:.3f} s collides even along the repaired path; "
                        "move the neighbouring keyframes apart or add a keyframe in between"
                    )
                added.append((idx[k] + idx[k + 1]) // 2)
                continue
            stop |= {idx[k], idx[k + 1]}  # rest to rest between corners: the straight, checked line
            if idx[k + 1] == b:
                kv[s + 1] = 0.0
            if idx[k] == a and kv[s].any():
                kv[s] = 0.0
                if s > 0:
                    return None, True, checks
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
    timer = SegmentTimer(_Solver(limits), limits, cfg)
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
        [p for seg in pieces for p in seg], key_t, path.poses[ki], late, checks + path.collision_checks
    )
