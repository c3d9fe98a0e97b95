"""A video end to end (engine side, pure compute): one pose per keyframe, optimised in order of first appearance.

DESIGN §4 "Gradient search", "Refinement", "Losses" and "Transition success". Each keyframe is searched through the
self-model and refined on the renderer (collision checked), like a still (:mod:`studio.imitate.still`), in one of
two modes:

- ``independent``: every keyframe alone, from a fresh batch of the self-exploration sampler (``first`` search);
- ``sequential``: the first keyframe from scratch (``first``), each later one from the previous keyframe's final
  pose + N(0, ``next.init_noise`` = 0.05 rad) (``next`` search; the paper's 128 × 1200).

``retrieve`` (on in ``CPU_SEQUENCE``, off in the paper's ``PAPER_SEQUENCE``) seeds each keyframe searched from
scratch like a still target (:mod:`studio.imitate.seeding`): the retrieval's best distinct poses, block-swept, fill
the first rows of its search batch and stay in the pool its refinement starts from, all scored with the temporal
term when the keyframe has one. Inherited keyframes keep the previous pose as their only seed.

Switches: ``expressive`` adds ``L_expr`` on the keyframe's expressive region; ``temporal`` adds
``L_temp = w_temporal·‖θ − θ*_{k−1}‖²`` against the previous keyframe's final pose to the search *and* to the
refinement (a refinement that jumps away from the previous pose would break the transition the search kept).

Every keyframe reports two sets of loss components of its rendered shadow: ``loss``, what its row optimised (NaN
where that row does not compute a term), and ``evaluation``, the same measure for every row (the expressive term
whenever expressive masks were given, the temporal term against the previous keyframe for k ≥ 1), from which
:mod:`studio.imitate.transitions` judges the transitions (``SequenceResult.transitions``).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from studio.errors import ClosedError, ProgressFn, staged, stopped
from studio.imitate.candidates import refine_best, rendered_pool
from studio.imitate.config import CPU_SEQUENCE, LossConfig, SequenceConfig
from studio.imitate.live_best import LiveBest
from studio.imitate.search import gradient_search
from studio.imitate.sequence_result import KeyframeResult, SequenceResult
from studio.imitate.still import Imitator
from studio.imitate.together import Stretch, eval_loss, refine_show, score_keyframe
from studio.learn.selfmodel import SelfModel

log = logging.getLogger(__name__)


BoxFn = Callable[[int, list], "tuple[np.ndarray, np.ndarray] | None"]  # (k, poses done) → keyframe k's box


class SequenceImitator:
    """Reusable machinery for sequences: an :class:`~studio.imitate.still.Imitator` (self-model, renderer,
    collision world, CLIP) shared by every keyframe. One made here is closed by ``close()`` (or a ``with`` block);
    one passed in stays the caller's."""

    def __init__(
        self,
        model: SelfModel | None = None,
        cfg: SequenceConfig | None = None,
        loss_cfg: LossConfig | None = None,
        clip=None,
        imitator: Imitator | None = None,
        device: str | None = None,
    ):
        self.cfg = cfg or CPU_SEQUENCE
        self._owns = imitator is None
        self.imitator = imitator or Imitator(model, loss_cfg=loss_cfg, clip=clip, device=device)
        self.model, self.renderer, self.refiner = self.imitator.model, self.imitator.renderer, self.imitator.refiner
        self.loss_cfg = self.imitator.loss_cfg

    def close(self) -> None:
        """Close the imitator if this object made it (idempotent)."""
        if self._owns:
            self.imitator.close()

    def __enter__(self) -> SequenceImitator:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def imitate(
        self,
        masks: np.ndarray,
        expressive: np.ndarray | None = None,
        progress: ProgressFn | None = None,
        cancel: threading.Event | None = None,
        cfg: SequenceConfig | None = None,
        best_pose: Callable[[np.ndarray], None] | None = None,
        previous: np.ndarray | None = None,
        box_for: BoxFn | None = None,
        roll: float = 0.0,
        pairs: Mapping[tuple[int, int], np.ndarray] | None = None,
        labels: Sequence[str] | None = None,
        items: Sequence[str] | None = None,
    ) -> SequenceResult:
        """Keyframe targets ``masks (K, S, S)`` uint8 (1 = shadow) in first-appearance order (all N frames work too:
        each is then its own keyframe), their expressive masks ``(K, S, S)`` or None → :class:`SequenceResult`.

        Reports :class:`~studio.errors.Progress` with stages "keyframe k/K: search" and "keyframe k/K: refine" (one
        keyframe: plain "search", "refine", ...), and
        for a keyframe seeded from scratch (``cfg.retrieve``) first "keyframe k/K: retrieve" and ".. : sweep" (and
        ".. : index" while the retrieval index is built, once per machine; see ``Imitator.imitate``).
        Setting ``cancel`` returns within a search or refinement step, with the keyframes finished before it and
        ``cancelled=True`` (a keyframe interrupted half-way is left out). ``cfg`` overrides this object's config
        for this call. ``best_pose(θ (21,) rad)`` gets each keyframe's improving collision-free poses and every
        report's best is the rendered loss of the pose last given there (live previews, as ``Imitator.imitate``).
        ``previous (21,) rad``: the pose of the keyframe before ``masks[0]`` (continuing a sequence: the first one
        is then searched from it when sequential and held to it by the temporal term); None: from scratch.
        ``box_for(k, done)`` → ``(lower (21,), upper (21,))`` rad or None: the box keyframe ``k``'s pose must keep
        given the poses ``done`` so far (e.g. its reach on the show's clock from the keyframes posed,
        :func:`~studio.motion.reach.clock_boxes`): retrieval, sweep, search and refinement all stay inside it.
        ``roll`` rad: the mount's roll; the masks are as the audience sees them, and every shadow and loss is the
        rolled mount's (:class:`~studio.imitate.framing.Framed`). ``pairs``: ``(i, j) → (21,)`` rad, the most
        keyframes ``i`` and ``j`` may differ per joint on the show's clock
        (:func:`~studio.motion.reach.reach_pairs`); given, with ``cfg.keep_clock`` and ``cfg.joint.enabled``,
        the keyframes are then refined together within them and ``box_for(k, [])`` (stage "together", after posing
        them last to first too with ``cfg.joint.both_orders``, stages "last to first: keyframe k/K: ...";
        :mod:`studio.imitate.together`; a cancel there keeps every keyframe, at the best poses found before it).
        ``labels``: what each keyframe is called in its stages and the log (default "keyframe k/K"; one keyframe:
        its stages unprefixed); ``items``: each keyframe's ``item`` on its progress reports (e.g. a project's
        keyframe id, for a panel to show the right target).
        """
        if self.refiner.closed:
            raise ClosedError("this SequenceImitator was closed; make a new one (or imitate inside its `with` block)")
        cfg = cfg or self.cfg
        masks = np.asarray(masks)
        if masks.ndim != 3 or len(masks) == 0:
            raise ValueError(f"masks must be a non-empty sequence (K, S, S), not an array of shape {masks.shape}")
        for given, what in ((labels, "labels"), (items, "items")):
            if given is not None and len(given) != len(masks):
                raise ValueError(f"{len(given)} {what} for {len(masks)} keyframes: give one a keyframe")
        if expressive is not None and np.shape(expressive) != masks.shape:
            raise ValueError(f"expressive masks {np.shape(expressive)} do not match the targets {masks.shape}")
        if cfg.expressive and expressive is None:
            raise ValueError(
                "the expressive term needs expressive masks (expressive_masks(video.masks)), "
                "or SequenceConfig(expressive=False)"
            )
        if cfg.retrieve and not self.imitator.cfg.retrieve:
            raise ValueError(
                "SequenceConfig(retrieve=True) seeds keyframes from the retrieval index, which this imitator has off "
                "(ImitateConfig(retrieve=False)); use SequenceConfig(retrieve=False) or an imitator with retrieval"
            )
        t0 = time.perf_counter()
        done: list[KeyframeResult] = []
        n = len(masks)
        for k in range(n):
            if stopped(cancel):
                break
            prev = done[-1].theta if done else previous
            exp_k = None if expressive is None else expressive[k]
            box = None if box_for is None else box_for(k, [d.theta for d in done])
            with self.refiner.bounded(box):
                label = f"keyframe {k + 1}/{n}" if labels is None else labels[k]
                stages = progress if n == 1 and labels is None else staged(progress, f"{label}: ")
                if items is not None:
                    stages = staged(stages, "", item=items[k])
                r = self._keyframe(cfg, k, masks[k], exp_k, prev, stages, cancel, best_pose, roll)
            if r is None:  # cancelled half-way
                break
            done.append(r)
            log.info(
                "%s: total %.4f (base %.4f, image %.4f) in %.1f s",
                label,
                r.loss["total"],
                r.evaluation["base"],
                r.total("image"),
                r.seconds,
            )
        cancelled = len(done) < n
        if not cancelled and pairs is not None and cfg.keep_clock and cfg.joint.enabled and n > 1:
            done = self._together(done, masks, expressive, cfg, pairs, box_for, previous, roll, progress, cancel)
        return SequenceResult(done, cfg, n, time.perf_counter() - t0, cancelled)

    def _together(self, done, masks, expressive, cfg, pairs, box_for, previous, roll, progress, cancel) -> list:
        """The finished keyframes refined together (:func:`~studio.imitate.together.refine_show`: in the better of
        both orders with ``cfg.joint.both_orders``)."""
        box_of = None if box_for is None else (lambda k: box_for(k, []))
        stretch = Stretch(masks, expressive, pairs, box_of, previous, roll)
        scored, got = refine_show(self, stretch, np.stack([d.theta for d in done]), cfg, progress, cancel)
        log.info("keyframes together (%s): %.4f → %.4f in %.1f s", "last to first" if got.chosen else "first to last",
                 got.start_loss, got.loss, got.seconds)  # fmt: skip
        share = got.seconds / len(done)  # the together step's time, shared out
        return [
            replace(d, theta=g.theta, shadow=g.shadow, loss=g.loss, evaluation=g.evaluation,
                    collision_free=g.collision_free, seconds=d.seconds + share, timings=d.timings | {"together": share})
            for d, g in zip(done, scored, strict=True)
        ]  # fmt: skip

    def _keyframe(
        self, cfg, k, target, expressive, prev, stages, cancel, best_pose=None, roll=0.0
    ) -> KeyframeResult | None:
        """Keyframe ``k`` searched and refined (``stages``: its progress, named as the caller calls it)."""
        t0 = time.perf_counter()
        framed = self.imitator.framed(target, expressive if cfg.expressive else None, roll)
        loss_fn, refiner = framed.exact, framed.refiner
        prev_t = prev if (cfg.temporal and prev is not None) else None  # the temporal term's θ*_{k−1}
        inherit = cfg.mode == "sequential" and prev is not None
        search_cfg = replace(cfg.next if inherit else cfg.first, seed=(cfg.next if inherit else cfg.first).seed + k)
        live = LiveBest(refiner, loss_fn, stages, best_pose, prev_t)  # what is shown: only ever better
        seeds, seed_s = None, 0.0
        if cfg.retrieve and not inherit:  # retrieval's first answer, then the block sweep of its best poses
            t_seed = time.perf_counter()
            seeds = self.imitator.seed(loss_fn, framed.ranking, prev_t, live.report, cancel, live.pose,
                                       k=search_cfg.batch, sweep=cfg.sweep, refiner=refiner)  # fmt: skip
            if stopped(cancel):
                return None
            seed_s = time.perf_counter() - t_seed
        t_search = time.perf_counter()
        search = gradient_search(
            self.model, framed.model, search_cfg, prev if inherit else None, prev_t, live.report, cancel, live.pose,
            starts=None if seeds is None else seeds.best.theta, box=refiner.box,
        )  # fmt: skip
        t1 = time.perf_counter()
        if search.cancelled:
            return None
        pool_theta, pool_loss, theta = search.batch_theta, search.batch_loss, search.theta
        if seeds is not None:  # ranked on the renderer, the seeds and the poses shown kept: never worse than those
            pool_theta, pool_loss, theta = rendered_pool(
                refiner, loss_fn, search.batch_theta, search.theta, seeds.best, prev_t, live.shown()
            )
        if cfg.refine_enabled:
            best = refine_best(refiner, loss_fn, pool_theta, pool_loss, cfg.candidates, cfg.refine,
                               live.report, cancel, prev_t, live.pose)  # fmt: skip
            if stopped(cancel):
                return None
            if best is not None and best.collision_free:
                theta = best.theta
        t2 = time.perf_counter()
        got = score_keyframe(refiner, loss_fn, eval_loss(self.imitator, loss_fn, target, expressive, cfg), theta,
                             prev_t, prev)  # fmt: skip
        return KeyframeResult(k, got.theta, got.shadow, got.loss, got.evaluation, got.collision_free, search.loss,
                              t2 - t0, {"seed": seed_s, "search": t1 - t_search, "refine": t2 - t1})  # fmt: skip


def imitate_sequence(
    model: SelfModel | None,
    masks: np.ndarray,
    expressive: np.ndarray | None = None,
    cfg: SequenceConfig | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    loss_cfg: LossConfig | None = None,
    clip=None,
) -> SequenceResult:
    """One sequence with a :class:`SequenceImitator` opened and closed here (see its ``imitate``: stages, cancel);
    ``model`` None loads the shipped self-model. Many sequences: keep one ``SequenceImitator`` open instead."""
    with SequenceImitator(model, cfg, loss_cfg=loss_cfg, clip=clip) as seq:
        return seq.imitate(masks, expressive, progress, cancel)
