"""The live answer of one target: the best collision-free pose shown so far, by its rendered-shadow loss.

Each stage of a still or a keyframe reports its own best through ``best_pose(θ)`` followed by a
:class:`~studio.errors.Progress` event, and those are not one measure: the gradient search's best is the
*self-model's* loss of a pose that may collide, a refinement run of the second candidate starts again above the first's
result, and with CLIP on the sweep reports no loss (NaN) until its poses are re-scored. :class:`LiveBest` sits between
the stages and the caller (the CLI's bars, the studio's preview): a pose is passed on only when it is collision-free and
its rendered loss (the objective, with the temporal term when the target has one) is below every pose passed on before,
and every report carries the loss of the pose on show. So the preview only ever gets better, and its number is the loss
of the shadow on screen. Every pose passed on is kept (:meth:`LiveBest.shown`), so a caller that pools candidates by
rendered loss can make sure the pose it keeps is never worse than one it showed.

Pure compute over a refiner (renderer + collision world); the poses a stage reports with its own rendered loss
(retrieval, sweep without CLIP, refinement) are taken at that loss, the others are scored once on the renderer.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from studio.errors import Progress, ProgressFn
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner


class LiveBest:
    """Filters one target's stream of reported poses (module doc) into an only-improving one.

    ``progress`` (the caller's :data:`~studio.errors.ProgressFn`) and ``best_pose(θ (21,) rad)`` are the caller's
    callbacks; :meth:`report` is the stages' ``progress`` and :meth:`pose` their ``best_pose``. ``rescore`` names the
    stages whose reported loss is not the rendered one (their poses are scored here)."""

    def __init__(
        self,
        refiner: Refiner,
        loss_fn: ImageLoss,
        progress: ProgressFn | None = None,
        best_pose: Callable[[np.ndarray], None] | None = None,
        theta_prev: np.ndarray | None = None,
        rescore: tuple[str, ...] = ("search",),
    ) -> None:
        self.refiner, self.loss_fn, self.theta_prev = refiner, loss_fn, theta_prev
        self._progress, self._best_pose, self._rescore = progress, best_pose, rescore
        self.loss = math.inf  # rendered loss of the pose on show (inf: none yet)
        self.theta: np.ndarray | None = None  # (21,) rad, the pose on show
        self._pending: np.ndarray | None = None  # the last pose a stage reported, judged at its next report
        self._shown: list[tuple[np.ndarray, float]] = []

    def pose(self, theta: np.ndarray) -> None:
        """A stage's ``best_pose`` hook: hold the pose until the stage's report that follows it."""
        self._pending = np.array(theta, dtype=np.float64)

    def report(self, p: Progress) -> None:
        """A stage's ``progress`` (a :data:`~studio.errors.ProgressFn`): judge the held pose (at ``p.best`` when
        the stage's loss is the rendered one), then pass ``p`` on with the loss of the pose on show as its best (NaN
        before the first)."""
        if self._pending is not None:
            theta, self._pending = self._pending, None
            rendered = p.stage.rsplit(": ", 1)[-1] not in self._rescore and math.isfinite(p.best)
            self._offer(theta, p.best if rendered else None)
        if self._progress:
            best = self.loss if math.isfinite(self.loss) else math.nan
            self._progress(Progress(p.stage, p.step, p.total, best, p.item))

    def shown(self) -> tuple[np.ndarray, np.ndarray]:
        """Every pose passed on, ``(M, 21)`` rad, and their rendered losses ``(M,)`` (all collision-free)."""
        if not self._shown:
            return np.empty((0, self.refiner.hand.dof)), np.empty(0)
        return np.stack([t for t, _ in self._shown]), np.array([v for _, v in self._shown])

    def _offer(self, theta: np.ndarray, loss: float | None) -> None:
        if loss is None:
            loss = float(self.refiner.score(self.loss_fn, theta[None], self.theta_prev)[0][0])
        if not loss < self.loss or bool(self.refiner.world.in_collision(theta, check=False)[0]):
            return
        self.loss, self.theta = loss, theta
        self._shown.append((theta, loss))
        if self._best_pose:
            self._best_pose(theta.copy())
