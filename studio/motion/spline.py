"""The one spline through a show's keyframes (DESIGN §4 "Motion"), pass 1 of the path (:mod:`studio.motion.path`)
and the source of the keyframe velocities (:mod:`studio.motion.plan`): a not-a-knot cubic through home + keyframes at
their times; a joint whose cubic leaves its limits (or a show with fewer than 3 poses) is interpolated linearly
instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline

from studio.sim.hand import Hand


@dataclass(frozen=True)
class KeyframeSpline:
    """The one spline through keyframes (DESIGN §4 "Motion"), shared by the path and the keyframe velocities.

    A not-a-knot cubic spline through ``poses (K, 21) rad`` at ``times (K,) s``; a joint whose cubic leaves its
    limits anywhere between the first and the last keyframe is interpolated linearly instead, as is every joint with
    fewer than 3 keyframes (or a cubic that is not finite). Keyframes are passed exactly.
    """

    times: np.ndarray  # (K,) s, strictly increasing
    poses: np.ndarray  # (K, 21) rad
    cubic: CubicSpline | None  # the not-a-knot spline of all joints; None when every joint is linear
    linear: np.ndarray  # (21,) bool: joints interpolated linearly

    def __call__(self, t: np.ndarray) -> np.ndarray:
        """Positions ``(T, 21)`` rad at times ``t (T,)`` (clamped to the keyframes' span); exact at keyframe times."""
        t = np.clip(np.atleast_1d(np.asarray(t, dtype=float)), self.times[0], self.times[-1])
        out = np.empty((len(t), self.poses.shape[1]))
        if self.cubic is not None:
            out[:] = self.cubic(t)
        for j in np.flatnonzero(self.linear):
            out[:, j] = np.interp(t, self.times, self.poses[:, j])
        hit = np.isin(t, self.times)
        out[hit] = self.poses[np.searchsorted(self.times, t[hit])]
        return out

    def key_velocities(self) -> np.ndarray:
        """``(K, 21)`` rad/s at the keyframes: the cubic's velocity, 0 for joints interpolated linearly."""
        v = np.zeros_like(self.poses)
        if self.cubic is not None:
            v[:, ~self.linear] = self.cubic(self.times, 1)[:, ~self.linear]
        return v


def _cubic_range(spline: CubicSpline) -> tuple[np.ndarray, np.ndarray]:
    """Exact ``(min, max)`` per joint, each (21,), of a piecewise cubic over its breakpoints' span."""
    c, h = spline.c, np.diff(spline.x)[:, None]  # c: (4, K-1, 21) coefficients of (s - x_i)^(3-k); h: (K-1, 1)
    a, b, d = 3 * c[0], 2 * c[1], c[2]  # p'(s) = a s² + b s + d
    with np.errstate(divide="ignore", invalid="ignore"):
        root = np.sqrt(np.maximum(b * b - 4 * a * d, 0.0))
        real = b * b - 4 * a * d >= 0
        quad = np.abs(a) > 1e-12
        r1 = np.where(quad, (-b + root) / (2 * a), np.where(np.abs(b) > 1e-12, -d / b, 0.0))
        r2 = np.where(quad, (-b - root) / (2 * a), 0.0)
    s = np.stack([np.zeros_like(r1), np.broadcast_to(h, r1.shape)] + [np.where(real, r, 0.0) for r in (r1, r2)])
    s = np.clip(np.nan_to_num(s), 0.0, h)  # candidates: both ends and the stationary points inside the piece
    p = ((c[0] * s + c[1]) * s + c[2]) * s + c[3]  # (4, K-1, 21)
    return p.min(axis=(0, 1)), p.max(axis=(0, 1))


def keyframe_spline(times: np.ndarray, poses: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> KeyframeSpline:
    """The keyframe spline of ``poses (K, 21) rad`` at ``times (K,) s`` within ``[lower, upper] (21,)`` rad."""
    times, poses = np.asarray(times, dtype=float), np.asarray(poses, dtype=float)
    if times.ndim != 1 or poses.shape[:1] != times.shape or len(times) == 0:
        raise ValueError(f"keyframes need times (K,) and poses (K, D), got {times.shape} and {poses.shape}")
    if (np.diff(times) <= 0).any():
        raise ValueError("keyframe times must be strictly increasing")
    linear = np.ones(poses.shape[1], dtype=bool)
    cubic = None
    if len(times) >= 3:
        cubic = CubicSpline(times, poses, bc_type="not-a-knot", axis=0)
        lo, hi = _cubic_range(cubic)
        linear = ~(np.isfinite(lo) & np.isfinite(hi) & (lo >= lower - 1e-9) & (hi <= upper + 1e-9))
        if linear.all():
            cubic = None
    return KeyframeSpline(times, poses, cubic, linear)


def spline_path(hand: Hand, key_times: np.ndarray, key_poses: np.ndarray, rate_hz: float) -> tuple:
    """Pass 1: ``(times (M,), poses (M, 21), key_index (K,))`` sampled from the keyframe spline at ``rate_hz``."""
    spline = keyframe_spline(key_times, key_poses, hand.lower, hand.upper)
    key_times = spline.times
    parts = [
        np.linspace(a, b, max(2, int(np.ceil((b - a) * rate_hz)) + 1))[:-1] for a, b in zip(key_times, key_times[1:])
    ]
    times = np.concatenate(parts + [key_times[-1:]])
    return times, spline(times), np.searchsorted(times, key_times)
