"""A project run's keyframes refined together (:mod:`studio.imitate.together`), after they were optimised one
after another and before the show is planned.

A run poses each keyframe within the servos' reach of those posed before it on the show's clock
(:func:`~studio.project.show_timing.keyframe_box`), so the first pose of a source, chosen for its own target alone,
fixes where the next ones can go. With the clock kept (``SequenceConfig.keep_clock``) and ``SequenceConfig.joint``
on, every stretch of two or more consecutive keyframes of one source that the run optimised is refined together
within their reach of one another and of every other current keyframe (held), in one job each. Keyframes the run
did not optimise (current, or the artist's) never move, except those a run before it posed and did not get to refine
(it was cancelled or failed first): each such result is saved as awaiting its refinement together
(``PoseResult.awaits``: "together"), so the next run refines it with its neighbours, as the first run would have, and
a resumed run makes the show an uninterrupted one makes. With ``joint.both_orders`` a stretch is first posed again
last to first, and refined from the order whose sum is lower (:func:`~studio.imitate.together.refine_show`). A
stretch's results are replaced only where a pose moved, from the same inputs, so they stay current.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Collection
from dataclasses import replace
from typing import Any

import numpy as np

from studio.imitate.config import SequenceConfig
from studio.jobs.engine import refine_together_job
from studio.jobs.events import JobState
from studio.jobs.job import Job
from studio.jobs.queue import JobQueue
from studio.motion.limits import JointLimits
from studio.motion.reach import reach_distances
from studio.project.jobs import project_loss
from studio.project.run_spread import place_in_source, source_keyframes
from studio.project.show_timing import reach_of, transition_times
from studio.project.status import ProjectHandle
from studio.sim.hand import load_hand

log = logging.getLogger(__name__)


def refines_together(seq: SequenceConfig) -> bool:
    """Whether a run with budgets ``seq`` refines its keyframes together after posing them (module doc)."""
    return seq.keep_clock and seq.joint.enabled


def awaiting_together(project: ProjectHandle) -> set[int]:
    """The keyframes whose current result awaits its refinement together (a run stopped before it)."""
    status = project.status()
    return {k for k, r in project.results.items() if r.awaits == "together" and k not in status.stale}


def to_refine_together(project: ProjectHandle, pending: Collection[int]) -> frozenset[int]:
    """The keyframes a run that poses ``pending`` then refines together: its stretches, with the results that
    await it (:func:`awaiting_together`)."""
    return frozenset(k for ids in together_stretches(project, {*pending, *awaiting_together(project)}) for k in ids)


def together_stretches(project: ProjectHandle, optimised: Collection[int]) -> list[list[int]]:
    """The maximal stretches of two or more consecutive keyframes of one source (first-appearance order) that are
    all in ``optimised``, each in order, sources in keyframe order."""
    out, seen = [], set()
    for kf in project.keyframes:
        if kf.id in seen:
            continue
        ids = source_keyframes(project, kf.id)
        seen.update(ids)
        stretch: list[int] = []
        for k in [*ids, None]:  # None ends the last stretch
            if k is not None and k in optimised:
                stretch.append(k)
                continue
            if len(stretch) > 1:
                out.append(stretch)
            stretch = []
    return out


def together_job(project: ProjectHandle, ids: list[int], cfg: Any, clip: Any = None, model_path: Any = None) -> Job:
    """One stretch ``ids`` (:func:`together_stretches`) refined together as ``cfg`` (a
    :class:`~studio.project.run.RunConfig`) keeps the clock → ``project.refined_together`` on completion (one edit:
    the results of the keyframes whose pose moved, the others no longer awaiting it)."""
    seq, s, status = cfg.sequence, project.state, project.status()
    hand = load_hand()
    names = hand.joint_names
    limits = JointLimits.from_hand(hand, cfg.plan.limits)
    far = reach_distances(transition_times(s, cfg.layout), limits, seq.clock_margin)
    at = {k: i for i, k in enumerate(ids)}
    pairs = {(at[a], at[b]): d for a in ids for b, d in far.get(a, {}).items() if b in at and at[a] < at[b]}
    current = {kf.id for kf in s.keyframes if kf.id in s.results and kf.id not in status.stale}
    held = {n: s.results[n].theta(names) for n in current - set(ids)}  # every other current pose stays put
    boxes = [reach_of(far.get(k, {}), held, limits) for k in ids]
    _, before = place_in_source(project, ids[0])
    sequential = seq.mode == "sequential"  # a run continues a source's keyframe from the one before only then
    previous = held.get(before) if sequential and before is not None else None
    if not sequential:
        seq = replace(seq, temporal=False)  # each keyframe was optimised alone: no temporal chain to keep
    targets = [project.keyframe_masks(k) for k in ids]
    masks = np.stack([np.array(t) for t, _ in targets])
    expressive = np.stack([np.array(e) for _, e in targets])
    inputs = {k: project.keyframe_inputs(k) for k in ids}
    start = {k: s.results[k] for k in ids}

    def apply(result: Any) -> None:
        scores, got = result
        order = ", posed last to first" if got.chosen else ""
        log.info("keyframes %d–%d together%s: sum %.4f → %.4f in %.1f s", ids[0], ids[-1], order, got.start_loss,
                 got.loss, got.seconds)  # fmt: skip
        share = got.seconds / len(ids)
        moved = {}  # keyframe → set_result's arguments, for each pose the refinement moved
        for k, sc in zip(ids, scores, strict=True):
            if not np.array_equal(sc.theta, start[k].theta(names)):
                moved[k] = {"pose": sc.theta, "loss": sc.loss, "shadow": sc.shadow, "inputs": inputs[k],
                            "evaluation": sc.evaluation, "collision_free": sc.collision_free,
                            "seconds": start[k].seconds + share}  # fmt: skip
        project.refined_together(list(ids), moved)  # one edit: the poses moved, and those kept no longer await it

    job = refine_together_job(
        masks, expressive, np.stack([start[k].theta(names) for k in ids]), pairs=pairs, boxes=boxes, cfg=seq,
        loss_cfg=project_loss(project, masks.shape[-1], clip), clip=clip, model_path=model_path, previous=previous,
        device=cfg.device, roll=project.mount.roll, ids=list(ids), apply=apply,
        title=f"keyframes {ids[0]}–{ids[-1]} together",
    )  # fmt: skip
    job.meta["keyframes"] = list(ids)
    return job


def refine_stretches(project: ProjectHandle, cfg: Any, clip: Any, queue: JobQueue, cancel: threading.Event | None,
                     model_path: Any, on_job: Callable[[Job, str], None] | None, report: Any) -> bool:  # fmt: skip
    """Every stretch of ``report.optimised`` and of the results awaiting it (:func:`together_stretches`) refined
    together, one job each on ``queue`` (``on_job`` told of each), in the run's ``report`` (a
    :class:`~studio.project.run_report.RunReport`); False when one failed or was cancelled (``report`` says so;
    the stretches finished before it are kept, the others still await it)."""
    for ids in together_stretches(project, {*report.optimised, *awaiting_together(project)}):
        job = queue.submit(together_job(project, ids, cfg, clip, model_path))
        if on_job is not None:
            again = ", posed last to first too" if cfg.sequence.joint.both_orders else ""
            on_job(job, f"refining keyframes {ids[0]}–{ids[-1]} together{again}, within their reach on the show's "
                        "clock")  # fmt: skip
        state = job.follow(cancel)
        if state != JobState.DONE:
            report.cancelled, report.error = state == JobState.CANCELLED, job.error
            what = "cancelled" if report.cancelled else f"failed ({job.error})"
            report.message = (f"refining keyframes {ids[0]}–{ids[-1]} together {what}; every keyframe optimised "
                              "before it is saved, and the next run refines them together")  # fmt: skip
            return False
        report.refined.extend(ids)
    return True
