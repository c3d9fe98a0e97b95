"""From a search's batch to the kept pose: the pool of candidates, its distinct best, each refined, the best kept.

Shared by a still target (:class:`~studio.imitate.still.Imitator`) and every keyframe of a sequence
(:class:`~studio.imitate.sequence.SequenceImitator`), so both pick and refine candidates the same way:

1. the pool: the search batch scored by the self-model (the paper), or on the renderer with the collision-free
   seeds added (:func:`rendered_pool`, the studio), every score with the temporal term when a sequence has one;
2. its ``k`` best *distinct* poses (:func:`distinct_best`: the batch often converges to a few basins);
3. each refined on the rendered shadow (:meth:`~studio.imitate.refine.Refiner.refine`), the lowest loss kept
   (:func:`refine_best`; a result that found no collision-free pose has loss +inf, so it is kept only when no
   candidate found one).

Pure compute over a refiner (renderer + collision world); progress and live previews go through callbacks.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import numpy as np

from studio.errors import ProgressFn, stopped
from studio.imitate.config import RefineConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner, RefineResult
from studio.imitate.retrieval import Retrieved


def rendered_pool(
    refiner: Refiner, loss_fn: ImageLoss, batch_theta: np.ndarray, fallback: np.ndarray,
    seeds: Retrieved | None = None, theta_prev: np.ndarray | None = None,
    shown: tuple[np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """A search batch ``(B, 21)`` scored on the renderer (colliding poses at +inf) with the collision-free
    ``seeds`` and ``shown`` poses ``(M, 21)`` / losses ``(M,)`` (:meth:`LiveBest.shown
    <studio.imitate.live_best.LiveBest.shown>`) appended → the refinement's pool ``(P, 21)``, its losses ``(P,)``
    and its best pose ``(21,)`` (``fallback`` when none is collision-free), so the pose kept is never worse than
    the best seed or the best pose shown."""
    loss = refiner.score(loss_fn, batch_theta, theta_prev)[0]
    loss[refiner.world.in_collision(batch_theta, check=False)] = np.inf
    for extra_theta, extra_loss in ([(seeds.theta, seeds.loss)] if seeds is not None else []) + (
        [shown] if shown else []
    ):
        batch_theta, loss = np.concatenate([batch_theta, extra_theta]), np.concatenate([loss, extra_loss])
    best = batch_theta[int(np.argmin(loss))] if np.isfinite(loss).any() else fallback
    return batch_theta, loss, np.array(best, dtype=np.float64)


def distinct_best(batch_theta: np.ndarray, batch_loss: np.ndarray, k: int, min_dist: float = 0.3) -> list:
    """Up to ``k`` of the best poses ``(B, 21)`` by loss, each at least ``min_dist`` rad (max over joints) from
    those already taken, best first (the batch often converges to a few basins: refine different ones)."""
    taken: list[np.ndarray] = []
    if k < 1:
        return taken
    for i in np.argsort(batch_loss):
        if not np.isfinite(batch_loss[i]):
            continue
        if all(np.abs(batch_theta[i] - t).max() >= min_dist for t in taken):
            taken.append(batch_theta[i])
        if len(taken) == k:
            break
    return taken


def refine_best(
    refiner: Refiner,
    loss_fn: ImageLoss,
    pool_theta: np.ndarray,
    pool_loss: np.ndarray,
    k: int,
    cfg: RefineConfig,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    theta_prev: np.ndarray | None = None,
    best_pose: Callable[[np.ndarray], None] | None = None,
) -> RefineResult | None:
    """Refine the ``k`` best distinct poses of the pool ``(P, 21)`` / ``(P,)`` one after another (each with the
    full ``cfg`` schedule, scored with the temporal term against ``theta_prev (21,)`` rad when given) → the result
    with the lowest loss, None when none ran (an empty pool, or ``cancel`` set before the first). Stage "refine"
    (:meth:`~studio.imitate.refine.Refiner.refine`), starting over for each candidate. Setting ``cancel`` stops
    within a refinement step and returns the best result so far (the caller reads ``cancel``)."""
    best = None
    for start in distinct_best(pool_theta, pool_loss, k):
        if stopped(cancel):
            break
        r = refiner.refine(loss_fn, start, cfg, progress, cancel, theta_prev=theta_prev, best_pose=best_pose)
        if best is None or r.loss < best.loss:
            best = r
        if r.cancelled:
            break
    return best
