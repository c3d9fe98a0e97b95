"""Seeds for a search from scratch, scored on the exact renderer: the retrieval's first answer, then the block
sweep of its best poses (the refinement pool keeps them: :func:`~studio.imitate.candidates.rendered_pool`).

The still :class:`~studio.imitate.still.Imitator` seeds every target this way, and a sequence every keyframe it
searches from scratch (the first one, or all of them when independent). Every score here is the rendered-shadow
loss of :meth:`~studio.imitate.refine.Refiner.score`, with the temporal term against ``theta_prev`` when a
sequence gives one, so the seeds, the pool and the final choice are ranked by the objective being optimised.

Pure compute over a refiner (renderer + collision world); progress and live previews go through callbacks.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from studio.errors import ProgressFn, report, stopped
from studio.imitate.config import SweepConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner
from studio.imitate.retrieval import RetrievalIndex, Retrieved
from studio.imitate.sweep import block_sweep, joint_blocks


@dataclass
class Seeds:
    """What seeding found (plain data): the first answer's poses and, when the sweep ran, the swept ones."""

    first: Retrieved  # the retrieval's distinct best poses, best first (row 0: the first answer), collision-free
    swept: Retrieved | None  # those poses after the block sweep, best first (None: sweep off, or cancelled first)
    timings: dict[str, float] = field(default_factory=dict)  # seconds: "first_answer" (the query), "sweep"

    @property
    def best(self) -> Retrieved:
        """The poses that seed the search: the swept ones when the sweep ran, else the retrieved ones."""
        return self.swept if self.swept is not None else self.first


def retrieve(
    index: RetrievalIndex, refiner: Refiner, loss_fn: ImageLoss, target: np.ndarray, k: int,
    theta_prev: np.ndarray | None = None,
) -> Retrieved:  # fmt: skip
    """The ``k`` best distinct collision-free poses of ``index`` for ``target (R, R)``, ranked by the rendered
    loss of ``loss_fn`` (+ the temporal term against ``theta_prev (21,)`` rad when given), best first. Within a
    :meth:`~studio.imitate.refine.Refiner.bounded` box, the shortlist is taken into the box first (clipped; those
    that then collide are left out, unless all do)."""
    if refiner.box is None:
        return index.query(target, lambda th: refiner.score(loss_fn, th, theta_prev)[0], k)
    t0 = time.perf_counter()
    lo, hi = refiner.lower, refiner.upper

    def boxed(th: np.ndarray) -> np.ndarray:
        inside = np.clip(th, lo, hi)
        loss = refiner.score(loss_fn, inside, theta_prev)[0]
        hit = refiner.world.in_collision(inside, check=False)
        return np.where(hit & ~hit.all(), np.inf, loss)

    got = index.query(target, boxed, k)
    theta = np.clip(got.theta, lo, hi)
    return Retrieved(theta, got.loss, time.perf_counter() - t0)


def sweep(
    refiner: Refiner,
    cfg: SweepConfig,
    loss_fn: ImageLoss,
    first: Retrieved,
    theta_prev: np.ndarray | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    best_pose: Callable[[np.ndarray], None] | None = None,
) -> Retrieved:
    """Block-sweep the ``cfg.starts`` best of the ``first`` poses; the rest follow unchanged. Returns them all under
    ``loss_fn``, best first, each still collision-free. Stage "sweep" after every block (step: blocks done over all
    starts, of ``starts × passes × blocks``: the step jumps when a start stops early; best: the best loss so far).

    With CLIP on, the thousands of draws are scored by the pixel terms alone (CLIP on every draw would take
    minutes on a CPU) and the swept poses are then re-scored under the full loss; ``best`` is then NaN until
    that last report, which carries the full loss (a pixel loss is not the objective's number)."""
    t0 = time.perf_counter()
    rng = np.random.default_rng(cfg.seed)
    hand = refiner.hand
    blocks = joint_blocks(hand)
    pixel_fn = loss_fn.pixel_only()
    theta = first.theta.copy()
    loss = refiner.score(pixel_fn, theta, theta_prev)[0] if pixel_fn is not loss_fn else first.loss.astype(float)
    n = min(cfg.starts, len(theta))
    best = [float(loss.min())]

    def on_better(th: np.ndarray, value: float) -> None:
        if value < best[0]:
            best[0] = value
            if best_pose:
                best_pose(th)

    def score(th: np.ndarray) -> np.ndarray:
        return refiner.score(pixel_fn, th, theta_prev)[0]

    def collides(th: np.ndarray) -> np.ndarray:
        return refiner.world.in_collision(th, check=False)

    per_start = cfg.passes * len(blocks)  # the most blocks one start can take; the bar jumps when it stops early
    pixel = pixel_fn is not loss_fn  # CLIP on: the draws' losses are not the objective's, none is reported

    def shown() -> float:
        return math.nan if pixel else best[0]

    def on_block(k: int) -> ProgressFn | None:  # one start's blocks → steps over all starts
        if progress is None:
            return None
        return lambda p: report(progress, "sweep", k * per_start + p.step, n * per_start, shown())

    for k in range(n):
        if stopped(cancel):
            break
        theta[k], loss[k], _ = block_sweep(
            theta[k], float(loss[k]), blocks, refiner.lower, refiner.upper, score, collides, cfg, rng, cancel,
            on_better, on_block(k),
        )  # fmt: skip
        if not stopped(cancel):
            report(progress, "sweep", (k + 1) * per_start, n * per_start, shown())
    if pixel:
        loss = refiner.score(loss_fn, theta, theta_prev)[0]
        report(progress, "sweep", n * per_start, n * per_start, float(loss.min()))
    order = np.argsort(loss, kind="stable")
    return Retrieved(theta[order], loss[order], time.perf_counter() - t0)


def seed_poses(
    index: RetrievalIndex,
    refiner: Refiner,
    cfg: SweepConfig,
    loss_fn: ImageLoss,
    target: np.ndarray,
    k: int,
    theta_prev: np.ndarray | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    best_pose: Callable[[np.ndarray], None] | None = None,
    beside_sweep: Callable[[], None] | None = None,
) -> Seeds:
    """Retrieve ``k`` poses for ``target (R, R)`` (stage "retrieve": the first answer, reported to ``best_pose``),
    then sweep the best ``cfg.starts`` of them (stage "sweep"; none when ``cfg.starts`` is 0). ``beside_sweep``
    (e.g. warming torch) runs in a thread while the sweep's kernels, which release the GIL, run; it is joined
    before this returns. ``cancel`` stops the sweep between blocks (``swept`` then holds what it had)."""
    t0 = time.perf_counter()
    first = retrieve(index, refiner, loss_fn, target, k, theta_prev)
    timings = {"first_answer": time.perf_counter() - t0}
    if best_pose:
        best_pose(first.theta[0].copy())
    report(progress, "retrieve", 1, 1, float(first.loss[0]))
    swept = None
    if cfg.starts > 0 and not stopped(cancel):
        worker = None
        if beside_sweep is not None:
            worker = threading.Thread(target=beside_sweep, name="studio-beside-sweep", daemon=True)
            worker.start()
        try:
            swept = sweep(refiner, cfg, loss_fn, first, theta_prev, progress, cancel, best_pose)
        finally:
            if worker is not None:
                worker.join()
        timings["sweep"] = swept.seconds
    return Seeds(first, swept, timings)
