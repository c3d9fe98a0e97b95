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
from dataclasses import dataclass

import numpy as np

from studio.sim.hand import Hand
from studio.sim.sampling import finger_joint_indices


@dataclass(frozen=True)
class SweepConfig:
    """How many poses are swept and how hard (the studio's defaults; ``starts=0`` turns the sweep off)."""

    starts: int = 4  # distinct retrieved poses swept, best first (0: no sweep, the paper's method) [0, ∞)
    draws: int = 1024  # settings drawn for a finger's joints per block [1, ∞)
    wrist_draws: int = 256  # settings drawn for the wrist (one joint) per pass [1, ∞)
    local_share: float = 0.25  # share of the draws taken near the block's current setting, not uniform [0, 1]
    local_sigma: float = 0.15  # std, rad, of those local draws (clipped to the limits) (0, ∞)
    passes: int = 3  # at most this many passes over all blocks; stops after a pass that improves nothing [1, ∞)
    checks: int = 16  # a block's best improving draws checked for collisions, best first, before moving on [1, ∞)
    seed: int = 0  # seed of the draws [0, ∞)

    def __post_init__(self) -> None:
        if self.starts < 0 or self.draws < 1 or self.wrist_draws < 1 or self.passes < 1 or self.checks < 1:
            raise ValueError("sweep needs starts ≥ 0 and draws, wrist_draws, passes, checks ≥ 1")
        if not 0.0 <= self.local_share <= 1.0 or self.local_sigma <= 0:
            raise ValueError("sweep local_share must be in [0, 1] and local_sigma > 0")


PAPER_SWEEP = SweepConfig(starts=0)  # the paper has no sweep


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
    on_block: Callable[[int], None] | None = None,
) -> tuple[np.ndarray, float, int]:
    """Sweep one pose ``theta (21,)`` rad (collision-free, with rendered loss ``loss``) block by block.

    Returns the best pose found ``(21,)``, its loss (never above ``loss``; the pose stays collision-free) and the
    number of poses scored. ``on_better(θ, loss)`` is called at each improvement, ``on_block(done)`` after each
    block with the blocks done so far (at most ``passes × len(blocks)``); ``cancel`` stops between blocks.
    """
    theta = np.asarray(theta, dtype=np.float64).copy()
    scored = done = 0
    for _ in range(cfg.passes):
        improved = False
        order = [blocks[0]] + [blocks[i] for i in 1 + rng.permutation(len(blocks) - 1)] if blocks else []
        for block in order:
            if cancel is not None and cancel.is_set():
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
            if on_block:
                on_block(done)
        if not improved:
            break
    return theta, loss, scored
