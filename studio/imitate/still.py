"""One still target end to end (engine side, pure compute): search the self-model, refine on the renderer.

``Imitator`` holds the self-model, the renderer, the collision world and (optionally) CLIP, so many targets
(``evaluate``) reuse them. It returns plain data; the CLI and the studio write files and review logs.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from studio.assets import asset
from studio.errors import ClosedError, ProgressFn, report, stopped
from studio.imitate.candidates import refine_best, rendered_pool
from studio.imitate.config import (
    CPU_REFINE,
    STUDIO_SEARCH,
    ImitateConfig,
    LossConfig,
    RefineConfig,
    SearchConfig,
    SweepConfig,
)
from studio.imitate.framing import Framed, Framer
from studio.imitate.index_cache import cached_index
from studio.imitate.kernels import compile_first
from studio.imitate.live_best import LiveBest
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner
from studio.imitate.retrieval import RetrievalConfig, RetrievalIndex
from studio.imitate.roll_search import Apart, RollChoice, RollSearchConfig, check_roll, choose_roll
from studio.imitate.search import SearchResult, gradient_search
from studio.imitate.seeding import Seeds, seed_poses
from studio.imitate.still_result import ImitationResult
from studio.learn.checkpoint import model_rig
from studio.learn.fanout import FanoutConfig
from studio.learn.selfmodel import SelfModel, load_selfmodel
from studio.sim.shadow import ShadowRenderer
from studio.targets.images import TargetConfig, load_target

DEFAULT_MODEL = asset("models/selfmodel_cpu128.pt", must_exist=False)  # the shipped 128² CPU self-model


class Imitator:
    """Reusable machinery for imitating still targets.

    Owns its refiner's collision world: ``close()`` (or the end of a ``with`` block) disconnects it, after which
    ``imitate`` raises :class:`~studio.errors.ClosedError`. The retrieval index (``config.retrieve``) is loaded (or
    built once per machine, :func:`~studio.imitate.index_cache.cached_index`) on the first ``imitate``, or given.
    """

    def __init__(
        self,
        model: SelfModel | None = None,
        model_path: Path | None = None,
        loss_cfg: LossConfig | None = None,
        clip=None,
        search: SearchConfig | None = None,
        refine: RefineConfig | None = None,
        device: str | None = None,
        config: ImitateConfig | None = None,
        retrieval: RetrievalConfig | RetrievalIndex | None = None,
        sweep: SweepConfig | None = None,
    ):
        if model is None:
            model, _ = load_selfmodel(Path(model_path or DEFAULT_MODEL), device=device)
        self.model = model
        self.hand = model.hand
        self.resolution = model.cfg.resolution
        self.loss_cfg = loss_cfg or LossConfig(use_clip=clip is not None, crop_size=self.resolution)
        self.clip = clip
        self.search_cfg = search or STUDIO_SEARCH
        self.refine_cfg = refine or CPU_REFINE
        self.cfg = config or ImitateConfig()
        self.sweep_cfg = sweep or SweepConfig()
        # the rig of the model's training shadows (a calibrated rig's geometry when it learnt from one)
        self.renderer = ShadowRenderer(self.hand, model_rig(getattr(model, "trained_rig", None), self.resolution))
        self.refiner = Refiner(self.renderer)
        self._index = retrieval if isinstance(retrieval, RetrievalIndex) else None
        self._warmed = False  # torch's first-use start-up is done (run beside the first sweep)
        self._compiled = False  # the compiled kernels were checked (and compiled when this install had not yet)
        self._framer = Framer(self.refiner, self.loss_fn)  # targets on a rolled mount (keeps its refiner)
        self.retrieval_cfg = self._index.cfg if self._index is not None else retrieval or RetrievalConfig()

    @property
    def candidates(self) -> int:
        return self.cfg.candidates

    def close(self) -> None:
        """Disconnect the refiner's collision world (idempotent)."""
        self.refiner.close()

    def __enter__(self) -> Imitator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def load(self, path: Path, cfg: TargetConfig | None = None) -> np.ndarray:
        """A target file → ``(R, R)`` uint8 mask framed like the model's images (TargetError when unusable)."""
        return load_target(path, size=self.resolution, cfg=cfg)

    def loss_fn(self, target: np.ndarray, expressive: np.ndarray | None = None) -> ImageLoss:
        return ImageLoss(target, self.loss_cfg, self.clip, expressive)

    def framed(self, target: np.ndarray, expressive: np.ndarray | None, roll: float) -> Framed:
        """``target (R, R)`` and its expressive mask as the audience sees them, on a mount rolled by ``roll`` rad
        (:class:`~studio.imitate.framing.Framed`: which loss scores what)."""
        return self._framer(target, expressive, roll)

    def retrieval_index(
        self, progress: ProgressFn | None = None, cancel: threading.Event | None = None,
        fanout: FanoutConfig | None = None,
    ) -> RetrievalIndex | None:  # fmt: skip
        """The retrieval index for this model's hand and rig (loaded or built on first use, then kept: stage "index"
        while it is built; a build spread as ``fanout`` says); None when ``cancel`` stopped its build. Every search
        from scratch and every roll search starts here, so the first one after an install compiles the kernels
        first, saying so (stage "compile", :mod:`studio.imitate.kernels`)."""
        if not self._compiled:
            compile_first(self.renderer, self.loss_cfg, progress)
            self._compiled = True
        if self._index is None:
            self._index = cached_index(self.renderer, self.retrieval_cfg, progress=progress, cancel=cancel,
                                       fanout=fanout)  # fmt: skip
        return self._index

    def imitate(
        self,
        target: np.ndarray,
        expressive: np.ndarray | None = None,
        refine: bool = True,
        progress: ProgressFn | None = None,
        cancel: threading.Event | None = None,
        best_pose: Callable[[np.ndarray], None] | None = None,
        roll: float = 0.0,
    ) -> ImitationResult:
        """Retrieve, search, then (optionally) refine ``target (R, R)`` as the audience sees it, on a mount rolled
        by ``roll`` rad (:class:`Framed`: the shadows and losses are the rolled mount's, against the target as it
        is). Reports :class:`~studio.errors.Progress` with stages
        "index" (building the retrieval index, once per machine), "retrieve" (the first answer), "sweep" (the block
        sweep of the best retrieved poses), "search" and "refine"; ``best_pose(θ (21,) rad)`` gets each pose that is
        collision-free and better than every one before it (the first answer, then the sweep's, the search's and the
        refinement's, :class:`~studio.imitate.live_best.LiveBest`), for live previews, and every report's best loss
        is the rendered loss of the pose last given there (NaN before the first).

        Setting ``cancel`` stops early: the result is then flagged ``cancelled`` and holds the best pose found so
        far (the searched pose when refinement had not started or found no collision-free pose).
        """
        if self.refiner.closed:
            raise ClosedError("this Imitator was closed; make a new one (or imitate inside its `with` block)")
        t0 = time.perf_counter()
        framed = self.framed(target, expressive, roll)
        loss_fn, refiner = framed.exact, framed.refiner
        live = LiveBest(refiner, loss_fn, progress, best_pose)  # what is shown: only ever better
        timings: dict[str, float] = {}
        seeds = self.seed(loss_fn, framed.ranking, progress=live.report, cancel=cancel, best_pose=live.pose,
                          refiner=refiner)  # fmt: skip
        if seeds is not None:
            timings |= seeds.timings  # index, first_answer, sweep
        first, swept = (seeds.first, seeds.swept) if seeds is not None else (None, None)
        t_s = time.perf_counter()
        search = gradient_search(
            self.model, framed.model, self.search_cfg, progress=live.report, cancel=cancel, best_pose=live.pose,
            starts=None if seeds is None else seeds.best.theta,
        )  # fmt: skip
        pool_theta, pool_loss, unrefined = self._select(loss_fn, search, seeds, live, refiner)
        t1 = time.perf_counter()
        timings["search"] = t1 - t_s
        with torch.no_grad():
            device = next(self.model.parameters()).device
            predicted = self.model(torch.tensor(unrefined[None], dtype=torch.float32, device=device))
        shadow0 = refiner.renderer.render_one(unrefined)
        _, comps0 = refiner.score(loss_fn, unrefined[None])
        collides0 = bool(refiner.world.in_collision(unrefined)[0])
        result = None
        theta, shadow, comps = unrefined, shadow0, {k: float(v[0]) for k, v in comps0.items()}
        cancelled = search.cancelled
        if refine and not cancelled:
            result = refine_best(refiner, loss_fn, pool_theta, pool_loss, self.candidates, self.refine_cfg,
                                 live.report, cancel, best_pose=live.pose)  # fmt: skip
            if result is not None and result.collision_free:
                theta, comps = result.theta, result.components
                shadow = refiner.renderer.render_one(theta)
        t2 = time.perf_counter()
        timings["refine"] = t2 - t1
        cancelled = cancelled or stopped(cancel)
        collision_free = not bool(refiner.world.in_collision(theta)[0])
        return ImitationResult(
            target=np.asarray(target, dtype=np.uint8),
            search=search,
            predicted=predicted[0, 0].cpu().numpy(),
            unrefined_theta=unrefined,
            unrefined_shadow=shadow0,
            unrefined_loss={k: float(v[0]) for k, v in comps0.items()},
            unrefined_collides=collides0,
            refine=result,
            theta=theta,
            shadow=shadow,
            loss=comps,
            collision_free=collision_free,
            seconds=t2 - t0,
            timings=timings,
            cancelled=cancelled,
            first=first,
            swept=swept,
            roll=float(roll),
        )

    def choose_roll(
        self,
        targets: np.ndarray,
        cfg: RollSearchConfig | None = None,
        progress: ProgressFn | None = None,
        cancel: threading.Event | None = None,
    ) -> RollChoice | None:
        """``--roll auto``: the one mount roll for ``targets (K, R, R)`` (a still: K = 1), chosen on their outlines
        (:func:`~studio.imitate.roll_search.choose_roll` on this imitator's index, loss and refiner); stage "index"
        while the index is built, then "roll" (a step per candidate swept). None when ``cancel`` stopped it."""
        index = self.retrieval_index(progress, cancel)
        if index is None:
            return None
        report(progress, "roll", 0, 1)
        choice = choose_roll(index, self.refiner, targets, self.loss_fn, cfg, progress, cancel)
        if stopped(cancel):
            return None
        report(progress, "roll", 1, 1, choice.loss)
        return choice

    def check_roll(
        self, targets: np.ndarray, deg: float, cfg: RollSearchConfig | None = None,
        progress: ProgressFn | None = None, cancel: threading.Event | None = None,
    ) -> list[Apart] | None:  # fmt: skip
        """The ``targets (K, S, S)`` a roll the artist set (``deg``) casts clearly worse than their own rolls would
        (:func:`~studio.imitate.roll_search.check_roll`); stages "index", "roll". None when ``cancel`` stopped it."""
        index = self.retrieval_index(progress, cancel)
        if index is None or stopped(cancel):
            return None
        report(progress, "roll", 0, 1)
        return check_roll(index, self.refiner, targets, self.loss_fn, deg, cfg)

    def seed(
        self,
        loss_fn: ImageLoss,
        target: np.ndarray,
        theta_prev: np.ndarray | None = None,
        progress: ProgressFn | None = None,
        cancel: threading.Event | None = None,
        best_pose: Callable[[np.ndarray], None] | None = None,
        k: int | None = None,
        sweep: SweepConfig | None = None,
        refiner: Refiner | None = None,
    ) -> Seeds | None:
        """The seeds of a search from scratch for ``target (R, R)`` under ``loss_fn`` (+ the temporal term against
        ``theta_prev (21,)`` rad): the retrieval's ``k`` best distinct poses (None: this imitator's search batch;
        stage "retrieve", the first answer), swept by ``sweep`` (None: ``self.sweep_cfg``; stage "sweep"); stage
        "index" while the index is built, once per machine; the shortlist and the sweep scored on ``refiner``
        (default this imitator's: a rolled one scores what a rolled mount casts, :class:`Framed`, while ``target``
        is what the index ranks by). None when ``config.retrieve`` is off (the paper's sampled batch) or ``cancel``
        stopped the index build. ``timings`` has "index" too."""
        if not self.cfg.retrieve:
            return None
        t0 = time.perf_counter()
        index = self.retrieval_index(progress, cancel)
        if index is None:  # cancelled while the index was built: no seeds (the caller sees the cancel)
            return None
        t_index = time.perf_counter() - t0
        seeds = seed_poses(
            index, refiner or self.refiner, sweep or self.sweep_cfg, loss_fn, target, k or self.search_cfg.batch,
            theta_prev, progress, cancel, best_pose, beside_sweep=None if self._warmed else self._warm_model,
        )  # fmt: skip
        seeds.timings["index"] = t_index
        return seeds

    def _warm_model(self) -> None:
        """torch's lazy start-up, paid beside the sweep's numba kernels (which release the GIL) instead of when the
        search starts (where a cancel during the sweep would wait for it): the first forward pass sets up the
        kernels. (The search's optimiser imports nothing: :mod:`studio.imitate.adam`.)"""
        device = next(self.model.parameters()).device
        with torch.no_grad():
            self.model(torch.zeros((1, self.hand.dof), dtype=torch.float32, device=device))
        self._warmed = True

    def _select(
        self, loss_fn: ImageLoss, search: SearchResult, seeds: Seeds | None, live: LiveBest, refiner: Refiner
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The refinement's candidate pool ``(P, 21)`` with its losses ``(P,)``, and the unrefined pose ``(21,)``.

        ``select="model"`` (the paper): the search batch by its self-model loss, the unrefined pose its best.
        ``"rendered"``: the search batch scored on the renderer (colliding poses excluded), the seeds and every
        pose shown so far (all collision-free) form the pool; the unrefined pose is its best (so never worse than
        the first answer or any pose the caller was shown)."""
        if self.cfg.select == "model":
            return search.batch_theta, search.batch_loss, search.theta
        return rendered_pool(refiner, loss_fn, search.batch_theta, search.theta,
                             None if seeds is None else seeds.best, shown=live.shown())  # fmt: skip
