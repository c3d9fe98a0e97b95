"""What the planning tests share: the hand, its limits, keyframe helpers, the crossing move, and the checks every
planned trajectory must pass (limits on the 40 Hz grid, no collision at 160 Hz, keyframes exact)."""

from __future__ import annotations

import numpy as np

from studio.motion.limits import JointLimits
from studio.motion.plan import Keyframes
from studio.sim.hand import load_hand

HAND = load_hand()
J = HAND.joint_names.index
LIMITS = JointLimits.from_hand(HAND)


def pose(**angles: float) -> np.ndarray:
    q = HAND.rest_pose().copy()
    for name, v in angles.items():
        q[J(name)] = v
    return q


def keyframes(times, poses, hold=None) -> Keyframes:
    n = len(times)
    hold = np.zeros(n, bool) if hold is None else np.asarray(hold)
    return Keyframes(np.asarray(times, float), np.asarray(poses, float), hold, [None] * n, [None] * n)


# Index finger swinging across the middle finger: both ends are free, the straight motion is not.
CROSS_A = pose(
    index_mcp_abd=-0.39,
    index_mcp_flex=-1.52,
    index_pip=0.12,
    middle_mcp_abd=-0.55,
    middle_mcp_flex=-0.7,
    middle_pip=0.36,
)
CROSS_B = CROSS_A.copy()
CROSS_B[[J("index_mcp_abd"), J("index_mcp_flex")]] = (-0.29, 0.53)


def assert_within_limits(traj, rate: float = 40.0) -> None:
    """Finite differences on the 40 Hz grid: position, velocity, acceleration and jerk within the limits."""
    h = 1.0 / rate
    t = np.arange(int(np.floor(traj.duration * rate)) + 1) * h
    q = traj.state(t)[0]
    tol = 1 + 1e-6
    assert (q >= LIMITS.lower - 1e-9).all() and (q <= LIMITS.upper + 1e-9).all()
    for order, limit, slack in ((1, LIMITS.velocity, 1e-9), (2, LIMITS.acceleration, 1e-6), (3, LIMITS.jerk, 1e-3)):
        d = np.abs(np.diff(q, n=order, axis=0)) / h**order
        assert (d <= limit * tol + slack).all(), (order, (d / limit).max())


def assert_collision_free(world, traj, rate: float = 160.0) -> None:
    t = np.arange(int(np.floor(traj.duration * rate)) + 1) / rate
    q = np.clip(traj.state(np.union1d(t, traj.key_times))[0], HAND.lower, HAND.upper)
    assert not world.in_collision(q).any()


def assert_keyframes_exact(result, kf: Keyframes) -> None:
    traj, show = result.trajectory, result.show
    start = 1 if result.home_added else 0
    times = traj.key_times[start:]
    if not traj.late:  # stretched segments (allow_late) shift the later keyframes, and say so
        assert np.array_equal(times, kf.times)
    assert np.array_equal(traj.state(times)[0], kf.poses)
    rows = np.searchsorted(show.times, times)
    assert np.array_equal(show.times[rows], times) and np.array_equal(show.positions[rows], kf.poses)
    assert [k.t for k in show.keyframes] == times.tolist()
