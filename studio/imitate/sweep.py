"""Block sweep: a global search over one finger (or the wrist) at a time, scored on the exact renderer.

The hand's shadow is the union of the palm's (set by the wrist) and five fingers' (four joints each), so a pose
is improved block by block: for one block, ``draws`` settings of its joints are drawn — most uniformly within the
joint limits, the rest near the block's current setting — while every other joint stays; the renders of all of
them are scored at once and the best collision-free one that lowers the loss is kept. A pass visits the wrist,
then the fingers in a random order; passes repeat until one improves nothing (or ``passes`` are done). Where the
gradient search and CMA-ES move all 21 joints a little, a block sweep can move one finger anywhere in its range,
which is what a shadow stuck in the wrong basin (a finger folded behind the palm instead of pointing) needs.

Pure compute: the caller gives ``score(θ (B, 21)) → (B,)`` losses and ``collides(θ (B, 21)) → (B,)`` bool.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from studio.errors import ProgressFn, report, stopped
from studio.imitate.config import SweepConfig
from studio.sim.hand import Hand
from studio.sim.sampling import finger_joint_indices


def joint_blocks(hand: Hand) -> list[np.ndarray]:
    """The sweep's blocks: the joints of no finger (the wrist) first, then each finger's joints, as index arrays."""
    fingers = [np.array(ix, dtype=np.int64) for ix in finger_joint_indices(hand).values() if ix]
    in_finger = set(np.concatenate(fingers).tolist()) if fingers else set()
    rest = np.array([i for i in range(hand.dof) if i not in in_finger], dtype=np.int64)
    return ([rest] if len(rest) else []) + fingers


def block_candidates(
    theta: np.ndarray, block: np.ndarray, n: int, lower: np.ndarray, upper: np.ndarray,
    cfg: SweepConfig, rng: np.random.Generator,
) -> np.ndarray:  # fmt: skip
    """``n`` copies of ``theta (21,)`` with the joints ``block`` redrawn → ``(n, 21)`` rad within the limits
    (a ``cfg.local_share`` of them near the current setting, the rest uniform)."""
    cand = np.repeat(np.asarray(theta, dtype=np.float64)[None], n, axis=0)
    lo, hi = lower[block], upper[block]
    n_local = int(round(cfg.local_share * n))
    uniform = rng.uniform(lo, hi, size=(n - n_local, len(block)))
    local = np.clip(theta[block] + rng.normal(0.0, cfg.local_sigma, size=(n_local, len(block))), lo, hi)
    cand[:, block] = np.concatenate([uniform, local])
    return cand


def block_sweep(
    theta: np.ndarray,
    loss: float,
    blocks: list[np.ndarray],
    lower: np.ndarray,
    upper: np.ndarray,
    score: Callable[[np.ndarray], np.ndarray],
    collides: Callable[[np.ndarray], np.ndarray],
    cfg: SweepConfig,
    rng: np.random.Generator,
    cancel: threading.Event | None = None,
    on_better: Callable[[np.ndarray, float], None] | None = None,
    progress: ProgressFn | None = None,
) -> tuple[np.ndarray, float, int]:
    """Sweep one pose ``theta (21,)`` rad (collision-free, with rendered loss ``loss``) block by block.

    Returns the best pose found ``(21,)``, its loss (never above ``loss``; the pose stays collision-free) and the
    number of poses scored. ``on_better(θ, loss)`` is called at each improvement; stage "sweep" is reported after each
    block (step: blocks done, of at most ``passes × len(blocks)``, fewer when a pass improves nothing; best: the
    loss so far); ``cancel`` stops between blocks.
    """
    theta = np.asarray(theta, dtype=np.float64).copy()
    scored = done = 0
    for _ in range(cfg.passes):
        improved = False
        order = [blocks[0]] + [blocks[i] for i in 1 + rng.permutation(len(blocks) - 1)] if blocks else []
        for block in order:
            if stopped(cancel):
                return theta, loss, scored
            n = cfg.wrist_draws if len(block) == 1 else cfg.draws
            cand = block_candidates(theta, block, n, lower, upper, cfg, rng)
            cand_loss = np.asarray(score(cand), dtype=np.float64)
            scored += n
            better = np.flatnonzero(cand_loss < loss - 1e-9)
            for i in better[np.argsort(cand_loss[better])][: cfg.checks]:
                if not bool(collides(cand[i : i + 1])[0]):
                    theta, loss, improved = cand[i].copy(), float(cand_loss[i]), True
                    if on_better:
                        on_better(theta.copy(), loss)
                    break
            done += 1
            report(progress, "sweep", done, cfg.passes * len(blocks), loss)
        if not improved:
            break
    return theta, loss, scored
