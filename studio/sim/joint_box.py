"""Boxes in the hand's joint space (pure compute): the poses within a per-joint distance of some given poses.

One rule for every box a pose must keep near others, whoever asks: a show's keyframe within the servos' reach of
its neighbours on the clock (:func:`studio.motion.reach.distance_box`) and a keyframe posed again or refined within
reach of those already posed (:func:`studio.imitate.joint_refine.posed_box`). Where two neighbours ask for more than
any pose can give (far apart, with little time), that joint is pinned to the middle of the two bounds that cross:
the nearest a pose gets to both.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

__all__ = ["box_near"]


def box_near(
    lower: np.ndarray, upper: np.ndarray, neighbours: Iterable[tuple[np.ndarray, np.ndarray]]
) -> tuple[np.ndarray, np.ndarray]:
    """The box ``(lower (J,), upper (J,))`` rad inside ``[lower, upper]`` and within ``d_n (J,)`` rad of every
    neighbour ``(θ_n (J,) rad, d_n)``; a joint whose bounds cross is pinned to their middle, within
    ``[lower, upper]`` (module doc)."""
    lower, upper = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    lo, hi = lower.copy(), upper.copy()
    for theta, d in neighbours:
        lo = np.maximum(lo, np.asarray(theta, dtype=np.float64) - d)
        hi = np.minimum(hi, np.asarray(theta, dtype=np.float64) + d)
    crossed = lo > hi
    mid = np.clip((lo + hi) / 2.0, lower, upper)
    return np.where(crossed, mid, lo), np.where(crossed, mid, hi)
