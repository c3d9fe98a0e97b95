"""Jobs bound to a :class:`~studio.project.project.Project`: inputs read when the job is made, results applied
through the Project API when it completes.

    queue = queue_for(project)                         # the project's one queue
    queue.submit(video_job(project, [k]))              # on completion: project.set_result(k, ...) for each
    queue.submit(show_job(project, keyframes))         # on completion: project.set_show(show, ...)

A project's run (:mod:`studio.project.run`, what every face runs) submits these jobs in order, the mount roll
chosen first (``roll_job``); ``video_job`` imitates its keyframes at the project's mount roll.

Each job captures the project's input fingerprint (``keyframe_inputs``/``show_inputs``) when it is made, so a
result whose inputs the artist changed while it ran is applied marked stale, never as current (the Project's rule).
A failed or cancelled job calls nothing on the project: it stays exactly as it was (same ``project.json``, same
undo list). A result is one edit (one undo step) per keyframe.
"""

from __future__ import annotations

import functools
import weakref
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from studio.jobs.engine import check_roll_job, choose_roll_job, imitate_video_job, plan_job
from studio.jobs.job import Job
from studio.jobs.queue import DEFAULT_WORKER, JobQueue
from studio.project.state import MountApart
from studio.project.status import ProjectHandle
from studio.sim.roll import roll_deg

if TYPE_CHECKING:
    from studio.imitate.config import LossConfig, SequenceConfig
    from studio.motion.plan import Keyframes, PlanConfig

_QUEUES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def queue_for(project: ProjectHandle, worker: str = DEFAULT_WORKER) -> JobQueue:
    """The project's job queue (made on first use; one per ``Project`` object; a closed one is replaced)."""
    queue = _QUEUES.get(project)
    if queue is None or queue._closed:
        queue = _QUEUES[project] = JobQueue(worker)
    return queue


def project_loss(project: ProjectHandle, side: int, clip: Any = None) -> LossConfig:
    """The project's loss weights for crops of ``side`` pixels; the CLIP terms only with an encoder."""
    w = project.weights
    return replace(w, use_clip=bool(w.use_clip and clip is not None), crop_size=side)


def video_job(
    project: ProjectHandle,
    keyframes: list[int] | None = None,
    *,
    cfg: SequenceConfig | None = None,
    clip: Any = None,
    model_path: Path | None = None,
    preview: int = 64,
    previous: np.ndarray | None = None,
    device: str | None = None,
    box: tuple[np.ndarray, np.ndarray] | None = None,
    awaits: str = "",
) -> Job:
    """Imitate the project's keyframes as one sequence, in first-appearance order (``keyframes``: ids, default
    all) → ``project.set_result`` for each on completion (:func:`.engine.imitate_video_job`). ``previous (21,)
    rad``: the pose of the keyframe before the first of them, when continuing a sequence; ``box``: the joint box
    ``(lower, upper) (21,)`` rad every one of them keeps (its reach on the show's clock,
    :func:`~studio.project.show_timing.keyframe_box`); ``awaits``: what the run still owes the results it saves
    (``"together"``: it refines them with their neighbours next, :mod:`~studio.project.run_together`)."""
    project_ids = [kf.id for kf in project.keyframes]
    chosen = set(project_ids if keyframes is None else keyframes)
    unknown = chosen - set(project_ids)
    if unknown:
        raise KeyError(f"no keyframe {sorted(unknown)} in {project.path} (it has {project_ids})")
    ids = [k for k in project_ids if k in chosen]
    if not ids:
        raise ValueError(f"no keyframes to imitate in {project.path}")
    pairs = [project.keyframe_masks(k) for k in ids]
    inputs = {k: project.keyframe_inputs(k) for k in ids}
    masks = np.stack([np.array(t) for t, _ in pairs])

    def apply(r) -> None:
        for k, kr in zip(ids, r.keyframes, strict=True):
            project.set_result(k, kr.theta, kr.loss, kr.shadow, inputs=inputs[k], evaluation=kr.evaluation,
                               collision_free=kr.collision_free, seconds=kr.seconds,
                               awaits=awaits)  # fmt: skip

    job = imitate_video_job(
        masks, np.stack([np.array(e) for _, e in pairs]), cfg=cfg,
        loss_cfg=project_loss(project, masks.shape[-1], clip), clip=clip, model_path=model_path, preview=preview,
        previous=previous, device=device, roll=project.mount.roll, box=box, apply=apply,
        title=f"keyframe {ids[0]}" if len(ids) == 1 else f"{len(ids)} keyframes",
    )  # fmt: skip
    job.meta["keyframes"] = list(ids)
    return job


def roll_job(project: ProjectHandle, *, model_path: Path | None = None) -> Job:
    """``--roll auto``: choose the one mount roll for every keyframe target of the project (their outlines, the
    project's weights, CLIP off) → ``project.set_chosen_roll`` on completion, which makes the keyframes optimised for
    another roll stale."""
    keyframes = project.keyframes
    masks = np.stack([np.array(project.keyframe_masks(kf.id)[0]) for kf in keyframes])

    def apply(r) -> None:
        if r is not None:
            project.set_chosen_roll(r.roll, loss=r.loss, upright_loss=r.upright_loss, apart=_named(keyframes, r.apart))

    job = choose_roll_job(masks, loss_cfg=project_loss(project, masks.shape[-1]), model_path=model_path, apply=apply)
    job.meta["keyframes"] = [kf.id for kf in keyframes]
    return job


def roll_check_job(project: ProjectHandle, *, model_path: Path | None = None, on_applied: Any = None) -> Job:
    """A roll the artist set: the keyframes it casts clearly worse than a roll of their own would (measured as for a
    roll auto chose) → ``project.set_roll_costs`` on completion (the roll and the keyframes' poses stay as they are),
    then ``on_applied()`` when given (a panel redraws)."""
    keyframes, roll = project.keyframes, project.mount.roll
    masks = np.stack([np.array(project.keyframe_masks(kf.id)[0]) for kf in keyframes])

    def apply(found) -> None:
        if found is not None:
            project.set_roll_costs(roll, _named(keyframes, found))
            if on_applied is not None:
                on_applied()

    job = check_roll_job(masks, roll_deg(roll), loss_cfg=project_loss(project, masks.shape[-1]),
                         model_path=model_path, apply=apply)  # fmt: skip
    job.meta["keyframes"] = [kf.id for kf in keyframes]
    return job


def _named(keyframes, found) -> list[MountApart]:
    """The roll search's ``Apart`` targets (indices into ``keyframes``) as the project keeps them."""
    return [MountApart(keyframes[a.target].id, keyframes[a.target].representative, a.loss, a.own_roll, a.own_loss)
            for a in found]  # fmt: skip


def search_renderer(model_path: Path | None = None) -> Any:
    """The renderer a keyframe job's search ranks the retrieval index with: the self-model's hand at its resolution
    (as :class:`~studio.imitate.still.Imitator` makes it; ``model_path`` None: the shipped self-model)."""
    from studio.imitate.still import DEFAULT_MODEL
    from studio.learn.checkpoint import model_rig, read_checkpoint
    from studio.learn.selfmodel import SelfModel
    from studio.sim.hand import load_hand
    from studio.sim.shadow import ShadowRenderer

    hand = load_hand()
    ckpt = read_checkpoint(Path(model_path or DEFAULT_MODEL), SelfModel.kind, hand.hash)
    return ShadowRenderer(hand, model_rig(ckpt.rig, SelfModel.config_from_dict(ckpt.config).resolution))


def index_needed(model_path: Path | None = None, retrieval: Any = None) -> bool:
    """Whether the first search on this machine would build the retrieval index (its cache missing): seconds of
    imports and a checkpoint read, so call it off the kernel's thread. ``retrieval``: a RetrievalConfig (None: the
    searches' default)."""
    from studio.imitate.index_cache import is_cached

    return not is_cached(search_renderer(model_path), retrieval)


def index_job(*, model_path: Path | None = None, retrieval: Any = None) -> Job:
    """Build the retrieval index the keyframe jobs search from into this machine's cache (:func:`search_ready`:
    stage "index", poses packed of its size), so that the first optimisation does not wait for it, compiling the
    kernels first when this install has not (stage "compile"); cancelled, it saves nothing. Its result: the index's
    size (0: cancelled)."""
    run = functools.partial(_build_index, model_path=model_path, retrieval=retrieval)
    return Job("index", run, title="retrieval index (first use only)")


def _build_index(report, cancel, *, model_path: Path | None, retrieval: Any) -> int:
    from studio.imitate.retrieval import RetrievalConfig

    # a machine without the index is a fresh install: its kernels compile here first (stage "compile"), not in the
    # first optimisation
    return (retrieval or RetrievalConfig()).size if search_ready(model_path, retrieval, report, cancel) else 0


def search_ready(
    model_path: Path | None = None, retrieval: Any = None, progress: Any = None, cancel: Any = None, fanout: Any = None
) -> bool:
    """What a search from scratch needs first, made now where this machine has not yet, in this order: the kernels
    compiled (stage "compile", once per install, :mod:`studio.imitate.kernels`), then the retrieval index built
    (stage "index", once per machine; spread as ``fanout``, a :class:`~studio.learn.fanout.FanoutConfig`, says)
    unless it is cached. One process of the machine does each at a time (``studio.home.cache_lock``). False when
    ``cancel`` stopped the index (nothing saved). The notebook's first-use job and a spread project run call it."""
    from studio.imitate.config import LossConfig
    from studio.imitate.index_cache import cached_index, is_cached
    from studio.imitate.kernels import compile_first

    renderer = search_renderer(model_path)
    compile_first(renderer, LossConfig(use_clip=False, crop_size=renderer.rig.resolution), progress)
    return is_cached(renderer, retrieval) or cached_index(renderer, retrieval, progress=progress, cancel=cancel,
                                                          fanout=fanout) is not None  # fmt: skip


def show_job(project: ProjectHandle, keyframes: Keyframes, *, cfg: PlanConfig | None = None) -> Job:
    """Plan a show through ``keyframes`` (the project's poses on their times) → ``project.set_show`` on
    completion (:func:`.engine.plan_job`)."""
    inputs = project.show_inputs()

    def apply(r) -> None:
        project.set_show(r.show, inputs=inputs)

    return plan_job(keyframes, cfg=cfg, show_title=project.state.title, apply=apply, title="show")
