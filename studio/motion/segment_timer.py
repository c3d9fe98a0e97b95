"""One keyframe segment's motion with Ruckig: the pieces, the solver, and the timer that threads via-points.

- :class:`Piece`: one Ruckig motion from a show time; :func:`evaluate` reads chained pieces at any times.
- :class:`RuckigSolver`: one state-to-state motion (position, velocity, zero acceleration at both ends) within the
  joint limits, time-synchronised, or phase-synchronised (the straight line) between two rests.
- :class:`SegmentTimer`: the pieces through a chosen set of via-points of a segment, each passed with the velocity
  of a clamped cubic spline through the segment's states (:func:`via_spline_velocities`), their durations split in
  proportion to the nominal times but never below each piece's shortest feasible time (:meth:`~SegmentTimer.shortest`).
- :func:`overshoots` and :func:`colliding`: the checks a timed piece must pass (joint limits, penetration at the
  check rate).

:mod:`studio.motion.timing` chains the segments into the show; :mod:`studio.motion.via_search` uses the timer for
its candidate via-points.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Synchronization, Trajectory
from scipy.interpolate import CubicSpline

from studio.motion.errors import PlanError
from studio.motion.limits import JointLimits
from studio.sim.physics import CollisionWorld


@dataclass
class Piece:
    """One Ruckig motion starting at ``t0`` (s, show time)."""

    t0: float
    traj: Trajectory

    @property
    def duration(self) -> float:
        return float(self.traj.duration)


def evaluate(pieces: list[Piece], t: np.ndarray) -> np.ndarray:
    """Position, velocity, acceleration ``(3, T, 21)`` of chained ``pieces`` at show times ``t (T,)``."""
    starts = np.array([p.t0 for p in pieces])
    idx = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(pieces) - 1)
    out = np.empty((3, len(t), pieces[0].traj.degrees_of_freedom))
    for n, (ti, k) in enumerate(zip(t, idx)):
        piece = pieces[k]
        out[:, n] = piece.traj.at_time(min(max(ti - piece.t0, 0.0), piece.duration))
    return out


class RuckigSolver:
    """Ruckig calls with the joint limits set once."""

    def __init__(self, limits: JointLimits):
        self.dof = len(limits.velocity)
        self.limits = limits
        self.ruckig = Ruckig(self.dof)
        self.inp = InputParameter(self.dof)
        self.inp.min_position = limits.lower.tolist()
        self.inp.max_position = limits.upper.tolist()
        self._scale = None  # the slow-down the limits are set for (set on a call's first need)

    def solve(
        self, p0, v0, p1, v1, duration: float | None, straight: bool = False, shortest: float | None = None
    ) -> Trajectory | None:
        """One motion (p0, v0, 0) → (p1, v1, 0) lasting at least ``duration`` s (None: as fast as the limits
        allow); None when Ruckig finds none within the limits. ``straight`` (both ends at rest): along the straight
        line p0 → p1, phase-synchronised.

        Ruckig fills a ``minimum_duration`` by reshaping each joint's profile on its own, which leaves the line
        (measured: up to 0.014 rad on moves of ~0.1 rad stretched 1.3×), so a straight motion given more time than
        its shortest is that shortest motion slowed down evenly: with the limits v/k, a/k², j/k³ the time-optimal
        line takes exactly k times as long, on the same line. ``shortest``: that shortest motion's duration when the
        caller has it (:meth:`SegmentTimer.shortest`), saving a Ruckig call.
        """
        if not straight or duration is None:
            return self._calc(p0, v0, p1, v1, duration, straight)
        if shortest is None or duration <= shortest:
            fastest = self._calc(p0, v0, p1, v1, None, True)
            if fastest is None or fastest.duration <= 0.0:  # none, or a hold (no line to follow)
                return self._calc(p0, v0, p1, v1, duration, True)
            if duration <= fastest.duration:  # (Ruckig reshapes even a minimum duration equal to the shortest)
                return fastest
            shortest = fastest.duration
        if shortest <= 0.0:  # a hold: no line to follow
            return self._calc(p0, v0, p1, v1, duration, True)
        return self._calc(p0, v0, p1, v1, None, True, scale=duration / shortest)

    def _calc(self, p0, v0, p1, v1, duration, straight: bool, scale: float = 1.0) -> Trajectory | None:
        """One Ruckig call with the limits slowed by ``scale`` (velocity / k, acceleration / k², jerk / k³)."""
        inp, zero, lim = self.inp, [0.0] * self.dof, self.limits
        if scale != self._scale:
            inp.max_velocity = (lim.velocity / scale).tolist()
            inp.max_acceleration = (lim.acceleration / scale**2).tolist()
            inp.max_jerk = (lim.jerk / scale**3).tolist()
            self._scale = scale
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
    (``studio.motion.spline.keyframe_spline``): it threads via-points between two keyframes whose velocities that
    spline has already fixed."""
    v = np.zeros_like(q)
    v[0], v[-1] = v0, v1
    if len(q) > 2:
        v[1:-1] = CubicSpline(tau, q, bc_type=((1, v0), (1, v1)), axis=0)(tau[1:-1], 1)
    return v


class SegmentTimer:
    """Times one keyframe segment through a chosen set of via-points of the path."""

    def __init__(self, solver: RuckigSolver, limits: JointLimits, velocity_margin: float = 0.95):
        self.solver, self.limits, self.velocity_margin = solver, limits, velocity_margin

    def via_velocities(self, tau: np.ndarray, q: np.ndarray, v0: np.ndarray, v1: np.ndarray, stop: np.ndarray):
        """Velocities (n, 21) at the states ``q (n, 21)``: the via spline's, within the limits, zero where ``stop``."""
        v = via_spline_velocities(tau, q, v0, v1)
        vmax = self.velocity_margin * self.limits.velocity
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

    def shortest(self, tau, q, v, stop) -> np.ndarray:
        """The shortest time ``(n − 1,)`` s of each piece through states ``(q, v)`` (``stop``: at rest; a piece
        between two rests is the straight, phase-synchronised line)."""
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
        return minimum

    def time(self, t0: float, t1: float, tau, q, v, stop) -> tuple[list[Piece] | None, float]:
        """Pieces from t0 to t1 through states (q, v); (None, feasible) when Σ shortest times > t1 − t0."""
        n = len(q) - 1
        straight = stop[:-1] & stop[1:]
        fastest = self.shortest(tau, q, v, stop)
        minimum = fastest.copy()  # raised where a duration proves blocked
        total = t1 - t0
        for _ in range(10):
            if minimum.sum() > total + 1e-9:
                return None, float(minimum.sum())
            d = _allocate(minimum, np.maximum(np.diff(tau), 1e-6), total)
            pieces, start = [], t0
            for k in range(n):
                tr = self.solver.solve(q[k], v[k], q[k + 1], v[k + 1], float(d[k]), bool(straight[k]), fastest[k])
                if tr is None or tr.duration > d[k] + 1e-9:  # a blocked interval: that duration is impossible
                    minimum[k] = d[k] + 1e-3 if tr is None else tr.duration
                    break
                pieces.append(Piece(start, tr))
                start += d[k]
            else:
                return pieces, float(minimum.sum())
        raise PlanError(f"could not fit the motion between t = {t0:.3f} s and t = {t1:.3f} s to its duration")


def overshoots(traj: Trajectory, limits: JointLimits, tol: float = 1e-9) -> bool:
    """True when the piece leaves a joint's position limits (Ruckig may swing out to fill a long duration)."""
    ext = traj.position_extrema
    lo = np.array([e.min for e in ext])
    hi = np.array([e.max for e in ext])
    return bool((lo < limits.lower - tol).any() or (hi > limits.upper + tol).any())


def colliding(world: CollisionWorld, pieces: list[Piece], t0: float, t1: float, rate: float):
    """Check-grid times ``(T,)`` in [t0, t1] (ends included) and their penetration flags ``(T,)``."""
    grid = np.arange(np.ceil(t0 * rate), np.floor(t1 * rate) + 1) / rate
    t = np.unique(np.concatenate([[t0], grid[(grid >= t0) & (grid <= t1)], [t1]]))
    pos = np.clip(evaluate(pieces, t)[0], world.hand.lower, world.hand.upper)
    return t, world.in_collision(pos, check=False)
