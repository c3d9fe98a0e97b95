"""Self-exploration pose sampler (DESIGN §1): 75 % uniform, 10 % one active finger, 15 % two active fingers."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from studio.sim.hand import Hand
from studio.sim.handgen import FINGERS


@dataclass(frozen=True)
class SamplerConfig:
    """How self-exploration poses are drawn. Ranges are the URDF limits (which hold the paper's ranges)."""

    p_uniform: float = 0.75  # share of poses with every joint uniform in its range
    p_one_finger: float = 0.10  # share with one active finger (others near rest)
    p_two_fingers: float = 0.15  # share with two active fingers (others near rest)
    rest_noise: float = 0.05  # std of the noise, rad, around rest for the inactive fingers
    wrist_always_active: bool = True  # in the finger modes the wrist is still drawn uniformly

    def __post_init__(self) -> None:
        total = self.p_uniform + self.p_one_finger + self.p_two_fingers
        if abs(total - 1.0) > 1e-9 or min(self.p_uniform, self.p_one_finger, self.p_two_fingers) < 0:
            raise ValueError(f"sampler mix must be non-negative and sum to 1, got {total}")


def finger_joint_indices(hand: Hand) -> dict[str, list[int]]:
    """``{finger: [indices of its joints in theta]}``, from the joint names (``<finger>_<joint>``)."""
    out: dict[str, list[int]] = {f: [] for f in FINGERS}
    for i, name in enumerate(hand.joint_names):
        finger = name.split("_", 1)[0]
        if finger in out:
            out[finger].append(i)
    return out


def sample_poses(
    hand: Hand, n: int, rng: np.random.Generator, cfg: SamplerConfig | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Draw ``n`` poses. Returns ``theta (n, 21)`` rad within limits and ``mode (n,)`` int8
    (0 uniform, 1 one active finger, 2 two active fingers)."""
    cfg = cfg or SamplerConfig()
    lo, hi = hand.lower, hand.upper
    mode = rng.choice(3, size=n, p=[cfg.p_uniform, cfg.p_one_finger, cfg.p_two_fingers]).astype(np.int8)
    uniform = rng.uniform(lo, hi, size=(n, hand.dof))
    near_rest = np.clip(hand.rest_pose() + rng.normal(0.0, cfg.rest_noise, size=(n, hand.dof)), lo, hi)
    fingers = finger_joint_indices(hand)
    names = list(fingers)
    active = np.zeros((n, hand.dof), dtype=bool)
    active[mode == 0] = True
    for k, count in ((1, 1), (2, 2)):
        rows = np.flatnonzero(mode == k)
        for r in rows:
            for f in rng.choice(len(names), size=count, replace=False):
                active[r, fingers[names[f]]] = True
    if cfg.wrist_always_active:
        finger_cols = {i for idx in fingers.values() for i in idx}
        other = [i for i in range(hand.dof) if i not in finger_cols]
        active[:, other] = True
    theta = np.where(active, uniform, near_rest)
    return theta, mode


def walk_poses(
    hand: Hand,
    n: int,
    rng: np.random.Generator,
    step_rad: float = 0.25,
    start: np.ndarray | None = None,
    bad: Callable[[np.ndarray], np.ndarray] | None = None,
    tries: int = 50,
) -> np.ndarray:
    """``(n, 21)`` poses of a random walk within the limits, each joint moving at most ``step_rad`` from one pose to
    the next (quick to play one after another: capturing real shadows to learn from). ``start (21,)`` defaults to a
    sampled pose; ``bad(theta (K, 21)) -> (K,) bool`` rejects steps (e.g. self-collisions; ``start`` must pass it):
    of ``tries`` candidate steps the first good one is taken, else the walk stays put for that pose."""
    if n < 1 or not step_rad > 0:
        raise ValueError("walk at least one pose with a positive step")
    lo, hi = hand.lower, hand.upper
    at = np.clip(start if start is not None else sample_poses(hand, 1, rng)[0][0], lo, hi)
    out = np.empty((n, hand.dof))
    for i in range(n):
        steps = np.clip(at + rng.uniform(-step_rad, step_rad, size=(tries, hand.dof)), lo, hi)
        good = np.flatnonzero(~bad(steps)) if bad is not None else np.arange(tries)
        if len(good):
            at = steps[good[0]]
        out[i] = at
    return out
