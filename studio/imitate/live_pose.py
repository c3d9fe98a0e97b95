"""A pose for one live frame within a time budget: retrieval, then a short refinement warm-started from the last pose.

The live mode (``shadow-studio live``) asks for a pose for every new camera target, 10+ times a second, on two
cores. :class:`LivePoser` answers each within ``budget_s``:

1. **Candidates.** The retrieval index ranks its poses against the target by the binary pixel loss (one popcount
   pass, ~15 ms for 200,000 poses); the ``shortlist`` best are rendered and scored exactly, together with the
   previous answer (the warm start: a hand holding a pose keeps it while the target holds still). Every score
   carries the temporal term ``w_temporal·‖θ − θ_prev‖²`` against the previous answer, so of two look-alike poses
   the one nearer the hand wins and the hand does not jump between them.
   Within a box (the servos' soft limits) the candidates are clipped into it first.
2. **Refinement.** The best candidate is hill-climbed (:meth:`~studio.imitate.refine.Refiner.refine`, collision-
   free proposals only) until the budget is spent or ``refine_steps`` are done.
3. **Safe to move to.** The answer is collision-free (every retrieval pose is, and refinement accepts only
   collision-free proposals), and so is the straight joint-space path from where the hand is commanded now
   (``from_theta``) to it, checked at ``path_checks`` points; otherwise the next best collision-free candidate whose
   path is free is taken, and when none is, :attr:`LivePose.path_free` is False (the caller holds).

On a mount rolled by ``roll`` (DESIGN §1) the target is scored as the audience sees it, as offline
(:class:`studio.imitate.framing.Framed`): only the index's ranking sees it turned into the unrolled hand's frame
(:mod:`studio.sim.roll`); every rendered score renders the pose as the rolled mount casts it and compares it with the
target as it is, so turning a hole or a thin part does not blur it. Pure compute over an index and a refiner; the
refiner's collision world belongs to the thread that calls :meth:`LivePoser.pose`.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, replace

import numpy as np

from studio.imitate.config import LivePoseConfig, LossConfig, RefineConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner
from studio.imitate.retrieval import RetrievalIndex
from studio.sim.roll import into_hand_frame


@dataclass(frozen=True)
class LivePose:
    """One frame's answer (plain data)."""

    theta: np.ndarray  # (21,) rad, the pose to move to (unrolled hand frame; the mount's roll turns its shadow)
    loss: float  # rendered base loss of its shadow (as the rolled mount casts it) against the target, no temporal
    total: float  # the objective: loss + w_temporal·‖θ − θ_prev‖² (= loss for the first frame)
    first_loss: float  # base loss of the best retrieved candidate before refinement
    path_free: bool  # the straight path from the commanded pose to theta is collision-free
    seconds: float  # time spent on this frame
    steps: int  # refinement steps run within the budget


class _Deadline:
    """A cancel event that is set once a moment has passed (or an outer event is): the refinement's time budget."""

    def __init__(self, until: float, outer: threading.Event | None):
        self.until, self.outer = until, outer

    def is_set(self) -> bool:
        return time.perf_counter() >= self.until or (self.outer is not None and self.outer.is_set())


class LivePoser:
    """Poses for a stream of targets (module doc); remembers the previous answer for the temporal term."""

    def __init__(
        self,
        index: RetrievalIndex,
        refiner: Refiner,
        cfg: LivePoseConfig | None = None,
        loss_cfg: LossConfig | None = None,
        roll: float = 0.0,
        box: tuple[np.ndarray, np.ndarray] | None = None,
    ):
        self.roll = float(roll)  # rad, the mount's roll about the light axis
        self.index = index
        self.refiner = refiner.with_roll(self.roll)  # renders as the rolled mount casts (the world is ``refiner``'s)
        self.box = (
            box  # (lower (21,), upper (21,)) rad the answers stay in (e.g. the servos' soft limits); None: joints
        )
        self.cfg = cfg or LivePoseConfig()
        res = refiner.renderer.rig.resolution
        base = loss_cfg or LossConfig(use_clip=False, crop_size=res)
        self.loss_cfg = replace(base, use_clip=False, w_temporal=self.cfg.w_temporal)
        self.previous: np.ndarray | None = None  # (21,) rad, the last answer
        self._rng = np.random.default_rng(self.cfg.seed)

    def reset(self) -> None:
        """Forget the previous answer (the next frame is searched without the temporal term)."""
        self.previous = None

    def turned(self, target: np.ndarray) -> np.ndarray:
        """A target seen on the backdrop ``(R, R)`` → the unrolled hand's frame (itself without a roll)."""
        return into_hand_frame(target, None, self.roll)[0] if self.roll else np.asarray(target, np.uint8)

    def pose(
        self, target: np.ndarray, from_theta: np.ndarray | None = None, cancel: threading.Event | None = None
    ) -> LivePose:
        """The pose for ``target (R, R)`` uint8 (1 = shadow, as seen on the backdrop), moving from the commanded
        pose ``from_theta (21,) rad`` (None: the previous answer). Becomes the previous answer when its path is
        free."""
        with self.refiner.bounded(self.box):
            return self._pose(target, from_theta, cancel)

    def _pose(self, target: np.ndarray, from_theta: np.ndarray | None, cancel: threading.Event | None) -> LivePose:
        t0 = time.perf_counter()
        cfg, prev = self.cfg, self.previous
        loss_fn = ImageLoss(np.asarray(target, np.uint8), self.loss_cfg)  # the target as the audience sees it
        rank = self.index.rank(self.turned(target), self.loss_cfg)
        m = min(cfg.shortlist, len(self.index))
        cands = np.clip(self.index.theta[np.argpartition(rank, m - 1)[:m]], self.refiner.lower, self.refiner.upper)
        if prev is not None:
            cands = np.concatenate([prev[None], cands])
        totals, _ = self.refiner.score(loss_fn, cands, prev)
        order = np.argsort(totals, kind="stable")
        first_loss = float(self._base(loss_fn, cands[order[:1]])[0])
        budget = _Deadline(t0 + cfg.budget_s, cancel)
        refine = RefineConfig(
            method="hill", restarts=cfg.refine_chains, steps=cfg.refine_steps, restart_noise=cfg.refine_sigma,
            sigma0=cfg.refine_sigma, decay=0.97, sigma_min=0.01, seed=int(self._rng.integers(2**32)),
            log_every=1,
        )  # fmt: skip
        got = self.refiner.refine(loss_fn, cands[order[0]], refine, cancel=budget, theta_prev=prev)  # type: ignore[arg-type]
        steps = len(got.curve)
        here = prev if from_theta is None else np.asarray(from_theta, np.float64)
        pool = [got.theta] if got.collision_free else []
        pool += [cands[i] for i in order[:4]]
        theta, path_free = pool[0], False
        for th in pool:
            if here is None or self._path_free(here, th):
                theta, path_free = th, True
                break
        total = float(self.refiner.score(loss_fn, theta[None], prev)[0][0])
        loss = float(self._base(loss_fn, theta[None])[0])
        if path_free:
            self.previous = np.array(theta, dtype=np.float64)
        return LivePose(np.array(theta), loss, total, first_loss, path_free, time.perf_counter() - t0, int(steps))

    def _base(self, loss_fn: ImageLoss, theta: np.ndarray) -> np.ndarray:
        """Base losses ``(B,)`` of poses ``(B, 21)`` (no temporal term)."""
        return self.refiner.score(loss_fn, theta)[0]

    def _path_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """The straight joint-space path from ``a`` to ``b`` (both (21,) rad) is collision-free at its check points."""
        n = self.cfg.path_checks
        if n == 0:
            return not bool(self.refiner.world.in_collision(b, check=False)[0])
        s = np.linspace(0.0, 1.0, n + 1)[1:, None]
        return not bool(self.refiner.world.in_collision(a + (b - a) * s, check=False).any())


def offline_first_answer(index: RetrievalIndex, refiner: Refiner, target: np.ndarray, roll: float = 0.0) -> float:
    """The base loss of the retrieval's first answer for ``target (R, R)`` (as the offline search starts from: the
    index's full shortlist, no temporal term; on a mount rolled by ``roll`` scored as :class:`LivePoser` scores): the
    reference a live pose is measured against."""
    turned = into_hand_frame(target, None, roll)[0] if roll else np.asarray(target, np.uint8)
    rolled = refiner.with_roll(roll)
    cfg = LossConfig(use_clip=False, crop_size=rolled.renderer.rig.resolution)
    loss_fn = ImageLoss(np.asarray(target, np.uint8), cfg)  # the target as the audience sees it
    return float(index.query(turned, lambda th: rolled.score(loss_fn, th)[0], 1).loss[0])
