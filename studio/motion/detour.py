"""A detour for the repair pass when noise recovery stalls: RRT-Connect in joint space, then shortcutting.

Noise recovery (±5° steps pulled toward the next target) cannot leave a local minimum, e.g. a finger that must
swing around its neighbour rather than through it. Then the repair walk asks for a detour between its last accepted
pose and the keyframe: two trees grow from both ends by straight collision-free steps and connect; the found path is
shortcut (straight jumps that stay collision-free replace runs of points) and resampled so no step is longer than
``max_step``. Every straight step is checked with the same ``motion_free`` the walk uses.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class DetourConfig:
    """RRT-Connect settings."""

    step: float = 0.25  # rad (max-norm) of one tree extension
    max_nodes: int = 3000  # nodes over both trees before giving up
    goal_bias: float = 0.1  # probability of sampling the other tree's root
    shortcut_tries: int = 60  # random shortcut attempts on the found path
    max_step: float = 0.15  # rad (max-norm) between consecutive output points


def _steer(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    d = np.abs(b - a).max()
    return b if d <= step else a + (b - a) * (step / d)


def rrt_connect(
    start: np.ndarray,
    goal: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    free: Callable[[np.ndarray, np.ndarray], bool],
    rng: np.random.Generator,
    cfg: DetourConfig | None = None,
) -> np.ndarray | None:
    """Poses ``(n, 21)`` from ``start`` to ``goal`` (both included) joined by collision-free straight steps, or None.

    ``free(a, b)``: True when the straight motion a → b (b included) is collision-free.
    """
    cfg = cfg or DetourConfig()
    trees = [([start], [-1]), ([goal], [-1])]  # (nodes, parent index)

    def nearest(nodes: list[np.ndarray], q: np.ndarray) -> int:
        return int(np.argmin(np.abs(np.asarray(nodes) - q).max(axis=1)))

    def extend(tree, q) -> int | None:
        nodes, parent = tree
        i = nearest(nodes, q)
        new = _steer(nodes[i], q, cfg.step)
        if not free(nodes[i], new):
            return None
        nodes.append(new)
        parent.append(i)
        return len(nodes) - 1

    def branch(tree, i) -> list[np.ndarray]:
        nodes, parent = tree
        out = []
        while i >= 0:
            out.append(nodes[i])
            i = parent[i]
        return out

    grow, other = 0, 1
    while len(trees[0][0]) + len(trees[1][0]) < cfg.max_nodes:
        root = trees[other][0][0]
        q = root if rng.random() < cfg.goal_bias else rng.uniform(lower, upper)
        i = extend(trees[grow], q)
        if i is not None:
            target = trees[grow][0][i]
            while True:  # connect: the other tree steps straight toward the new node
                j = extend(trees[other], target)
                if j is None:
                    break
                if np.abs(trees[other][0][j] - target).max() < 1e-12:
                    a, b = branch(trees[grow], i), branch(trees[other], j)
                    path = a[::-1] + b[1:] if grow == 0 else b[::-1] + a[1:]
                    return _resample(_shortcut(np.array(path), free, rng, cfg.shortcut_tries), cfg.max_step)
        grow, other = other, grow
    return None


def _shortcut(path: np.ndarray, free, rng: np.random.Generator, tries: int) -> np.ndarray:
    pts = list(path)
    for _ in range(tries):
        if len(pts) <= 2:
            break
        i, j = sorted(rng.choice(len(pts), 2, replace=False))
        if j - i > 1 and free(pts[i], pts[j]):
            pts = pts[: i + 1] + pts[j:]
    return np.array(pts)


def _resample(path: np.ndarray, max_step: float) -> np.ndarray:
    out = [path[0]]
    for a, b in zip(path[:-1], path[1:]):
        n = max(1, int(np.ceil(np.abs(b - a).max() / max_step)))
        out += [a + (b - a) * k / n for k in range(1, n + 1)]
    return np.array(out)
