"""How far the servos can move in the time a transition has: the clock the sequence optimisation keeps.

A transition of the show (:mod:`studio.motion.video_timing`) leaves one keyframe pose at rest and must reach the
next within the time the video gives it. Per joint, the fastest rest-to-rest move over a distance ``d`` under the
velocity, acceleration and jerk limits of :class:`~studio.motion.limits.JointLimits` (the planner's, Ruckig's
time-optimal profile) takes :func:`rest_to_rest_time`; its inverse :func:`reach` is the largest distance a joint can
cover in ``dt``. A keyframe must stay inside the box :func:`reach_box` of every keyframe already posed, so every
transition is one the servos can make at the video's clock (``margin`` keeps room for the planner's spline and
detours). Not only its direct neighbours: per joint, :func:`reach_distances` gives how far apart two keyframes may
be along the shortest chain of moves between them (the sum of each move's reach; difference constraints), so a
keyframe placed now never leaves one placed later without room (on a return A → B → C → A, B keeps what C needs to
reach both).

Closed form of the profile (``τ = a/j``): no acceleration plateau, ``T = (32 d / j)^(1/3)``; with one,
``d = a (τ + t_a)(2τ + t_a)``, ``T = 4τ + 2 t_a``; with a cruise at ``v``, ``T = 2 t_v + (d − v t_v) / v`` where
``t_v`` is the time to reach ``v`` from rest. ``tests/test_reach.py`` checks it against Ruckig itself.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

from studio.motion.limits import JointLimits
from studio.sim.joint_box import box_near


def _time_to_speed(v: np.ndarray, a: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Seconds from rest to speed ``v`` (jerk-limited; with an acceleration plateau when ``v ≥ a²/j``)."""
    return np.where(v * j >= a * a, v / a + a / j, 2.0 * np.sqrt(v / j))


def rest_to_rest_time(d: np.ndarray, limits: JointLimits) -> np.ndarray:
    """The fastest rest-to-rest move over distances ``d (…, J)`` rad, per joint → seconds ``(…, J)``."""
    d = np.abs(np.asarray(d, dtype=np.float64))
    v, a, j = limits.velocity, limits.acceleration, limits.jerk
    tau = a / j
    t_v = _time_to_speed(v, a, j)
    cruise = d >= v * t_v  # the accelerating and braking halves cover v·t_v together
    t_cruise = 2.0 * t_v + (d - v * t_v) / v
    t_jerk = np.cbrt(32.0 * d / j)
    plateau = j * t_jerk / 4.0 > a  # peak acceleration of the pure-jerk profile beyond the limit
    t_a = (-3.0 * tau + np.sqrt(tau * tau + 4.0 * d / a)) / 2.0
    t_plateau = 4.0 * tau + 2.0 * np.maximum(t_a, 0.0)
    return np.where(cruise, t_cruise, np.where(plateau, t_plateau, t_jerk))


def reach(dt: float, limits: JointLimits) -> np.ndarray:
    """The largest distance ``(J,)`` rad each joint can move from rest to rest in ``dt`` seconds (bisection on
    :func:`rest_to_rest_time`, to 1e-9 rad)."""
    n = len(limits.velocity)
    if not dt > 0:
        return np.zeros(n)
    lo, hi = np.zeros(n), np.full(n, float(limits.velocity.max() * dt) + 1.0)
    for _ in range(60):
        mid = (lo + hi) / 2.0
        fits = rest_to_rest_time(mid, limits) <= dt
        lo, hi = np.where(fits, mid, lo), np.where(fits, hi, mid)
    return lo


def reach_box(
    neighbours: Sequence[tuple[np.ndarray, float]], limits: JointLimits, margin: float = 0.9
) -> tuple[np.ndarray, np.ndarray]:
    """The joint box ``(lower (J,), upper (J,))`` rad a pose must keep to reach, and be reached from, every
    neighbour ``(θ_n (J,) rad, dt_n s)`` in ``margin · dt_n``: :func:`distance_box` at :func:`reach`."""
    return distance_box([(theta, reach(margin * float(dt), limits)) for theta, dt in neighbours], limits)


def distance_box(
    neighbours: Sequence[tuple[np.ndarray, np.ndarray]], limits: JointLimits
) -> tuple[np.ndarray, np.ndarray]:
    """The joint box ``(lower (J,), upper (J,))`` rad within ``d_n (J,)`` rad of every neighbour ``(θ_n (J,) rad,
    d_n)``, within the joint limits (:func:`studio.sim.joint_box.box_near`: where neighbours ask for more than any
    pose can give, two far apart with little time, that joint is pinned to the middle of the two bounds that cross,
    the nearest the servos get to both)."""
    return box_near(limits.lower, limits.upper, neighbours)


def reach_distances(
    times: Mapping[tuple[int, int], float], limits: JointLimits, margin: float = 0.9
) -> dict[int, dict[int, np.ndarray]]:
    """``k → n → (J,)`` rad: per joint, how far apart keyframes ``k`` and ``n`` may be so that every move on the
    way between them can be made: the shortest chain of moves ``times`` ((a, b) → s, either way) weighted by each
    move's :func:`reach` in ``margin · dt`` (Floyd–Warshall per joint). Boxing each keyframe by every posed one at
    these distances keeps every later box from crossing. Pairs with no chain between them are left out."""
    ids = sorted({i for pair in times for i in pair})
    at = {k: i for i, k in enumerate(ids)}
    n = len(ids)
    dist = np.full((n, n, len(limits.velocity)), np.inf)
    dist[np.arange(n), np.arange(n)] = 0.0
    for (a, b), dt in times.items():
        r = reach(margin * float(dt), limits)
        dist[at[a], at[b]] = dist[at[b], at[a]] = np.minimum(dist[at[a], at[b]], r)
    for m in range(n):
        dist = np.minimum(dist, dist[:, m : m + 1] + dist[m : m + 1, :])
    return {a: {b: dist[at[a], at[b]] for b in ids if b != a and np.isfinite(dist[at[a], at[b]]).all()} for a in ids}


def reach_pairs(
    times: Mapping[tuple[int, int], float], limits: JointLimits, margin: float = 0.9
) -> dict[tuple[int, int], np.ndarray]:
    """``(a, b) → (J,)`` rad with ``a < b``: :func:`reach_distances` once per pair of keyframes joined on the clock,
    what refining them together keeps (:mod:`studio.imitate.joint_refine`)."""
    far = reach_distances(times, limits, margin)
    return {(a, b): d for a, near in far.items() for b, d in near.items() if a < b}


def clock_boxes(
    times: Mapping[tuple[int, int], float], limits: JointLimits, margin: float = 0.9
) -> Callable[[int, list], tuple[np.ndarray, np.ndarray] | None]:
    """For a sequence optimised in keyframe order: ``box_for(k, done)`` → keyframe ``k``'s box from the poses
    ``done`` of keyframes ``0 … k−1`` at their :func:`reach_distances` on the clock (``times``:
    :func:`transition_times <studio.motion.video_timing.transition_times>`), None when no chain of moves joins it
    to any of them."""
    far = reach_distances(times, limits, margin)

    def box_for(k: int, done: list) -> tuple[np.ndarray, np.ndarray] | None:
        near = [(done[n], d) for n, d in far.get(k, {}).items() if n < len(done)]
        return distance_box(near, limits) if near else None

    return box_for
