"""Jobs that run the engine: imitate one keyframe, imitate a whole video, refine a show's keyframes together, choose
the mount roll, plan a show (play: :mod:`.play`).

Each factory returns a :class:`~studio.jobs.job.Job` whose ``run`` is a ``functools.partial`` of a
module-level function (so it runs in a thread or a spawned process alike) and whose ``apply`` is the caller's
callback (the Project's ``set_result``/``set_show``, or anything else), called only when the job completes. Every
engine call gets the job's cancel event and :meth:`~studio.jobs.events.Reporter.engine_progress`
as its ``progress``: each :class:`~studio.errors.Progress` becomes a job event as it is, with a ≤ 64² preview of the
current best pose's shadow (from the engine's ``best_pose`` hook) at most ~10 times a second. Engine modules are
imported inside the workers, so importing this module stays light.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from studio.jobs.events import PosePreview, Reporter
from studio.jobs.job import Job

if TYPE_CHECKING:
    import threading

    from studio.imitate.config import LossConfig, RefineConfig, SearchConfig, SequenceConfig, SweepConfig
    from studio.motion.plan import Keyframes, PlanConfig
    from studio.motion.show import Show
    from studio.targets.images import TargetConfig

Apply = Callable[[Any], None] | None
HOLES = "holes"  # expressive region of a still: the target's holes (DESIGN §4), none when it has none


def imitate_keyframe_job(
    target: np.ndarray | str | Path,
    expressive: np.ndarray | str | None = HOLES,
    *,
    search: SearchConfig | None = None,
    refine: RefineConfig | None = None,
    refine_enabled: bool = True,
    candidates: int = 4,
    sweep: SweepConfig | None = None,
    loss_cfg: LossConfig | None = None,
    clip: Any = None,
    model_path: Path | None = None,
    target_cfg: TargetConfig | None = None,
    preview: int = 64,
    roll: float = 0.0,
    apply: Apply = None,
    title: str = "",
) -> Job:
    """Search + refine one target (:meth:`studio.imitate.still.Imitator.imitate`) → ``ImitationResult``.

    ``target``: an image path (loaded with ``target_cfg``; a bad file fails the job with its ``TargetError``) or a
    mask ``(R, R)`` uint8 framed at the model's resolution. ``expressive``: a mask ``(R, R)``, ``"holes"`` (the
    target's holes) or None. ``search``/``refine``/``candidates``/``sweep`` default to the studio presets
    (``STUDIO_SEARCH``, ``CPU_REFINE``, ``SweepConfig()``); ``clip``: a CLIP encoder for the CLIP terms (None: off;
    an encoder object suits the thread worker); ``preview``: side of the live shadow previews (8–64; 0: none);
    ``roll``: the mount roll, rad, as for :func:`imitate_video_job` (``result.roll``; :func:`choose_roll_job` chooses
    one).
    """
    run = functools.partial(
        _imitate_keyframe, target=target, expressive=expressive, search=search, refine=refine,
        refine_enabled=refine_enabled, candidates=candidates, sweep=sweep, loss_cfg=loss_cfg, clip=clip,
        model_path=model_path, target_cfg=target_cfg, preview=preview, roll=roll,
    )  # fmt: skip
    name = title or (Path(target).name if isinstance(target, (str, Path)) else "keyframe")
    return Job("imitate-keyframe", run, apply, name)


def _imitate_keyframe(report: Reporter, cancel, *, target, expressive, search, refine, refine_enabled, candidates,
                      sweep, loss_cfg, clip, model_path, target_cfg, preview, roll=0.0):  # fmt: skip
    from studio.imitate.config import ImitateConfig
    from studio.imitate.still import Imitator
    from studio.targets.expressive import still_expressive

    config = ImitateConfig(candidates=candidates)
    with Imitator(None, model_path, loss_cfg, clip, search, refine, config=config, sweep=sweep) as im:
        if isinstance(target, (str, Path)):
            mask = im.load(Path(target), target_cfg)
        else:
            mask = np.asarray(target, dtype=np.uint8)
            r = im.resolution
            if mask.shape != (r, r):
                raise ValueError(
                    f"target mask is {mask.shape}; this model works at ({r}, {r}): load_target(..., size={r})"
                )
        exp = still_expressive(mask) if isinstance(expressive, str) and expressive == HOLES else expressive
        pv = PosePreview(im.hand, preview, roll=roll) if preview else None
        return im.imitate(
            mask, exp, refine=refine_enabled, progress=report.engine_progress(pv), cancel=cancel,
            best_pose=pv.pose if pv else None, roll=roll,
        )  # fmt: skip


def imitate_video_job(
    masks: np.ndarray,
    expressive: np.ndarray | None = None,
    *,
    cfg: SequenceConfig | None = None,
    loss_cfg: LossConfig | None = None,
    clip: Any = None,
    model_path: Path | None = None,
    preview: int = 64,
    previous: np.ndarray | None = None,
    device: str | None = None,
    roll: float = 0.0,
    box: tuple[np.ndarray, np.ndarray] | None = None,
    apply: Apply = None,
    title: str = "video",
) -> Job:
    """Every keyframe of a video in first-appearance order (:class:`studio.imitate.sequence.SequenceImitator`) →
    ``SequenceResult``. ``masks (K, S, S)`` uint8 keyframe targets and their expressive masks (``keyframe_targets``
    picks them from a video's frames); ``cfg`` defaults to ``CPU_SEQUENCE`` (its ``expressive`` term needs masks).
    Stages are "keyframe k/K: search" and "keyframe k/K: refine", after "keyframe k/K: retrieve" and ".. : sweep"
    for a keyframe seeded from scratch (``cfg.retrieve``). ``clip`` as for :func:`imitate_keyframe_job`;
    ``previous (21,) rad``: the pose before the first of these keyframes (continuing a sequence), None: none;
    ``device``: where the self-model runs (None: CUDA when present); ``roll``: the mount roll, rad (the targets are as
    the audience sees them; every shadow, loss and preview is the rolled mount's, and only the self-model's search
    sees them turned into the hand's frame, :class:`studio.imitate.framing.Framed`); ``box``: ``(lower, upper)
    (21,)`` rad every keyframe's pose keeps (its reach on the show's clock)."""
    run = functools.partial(
        _imitate_video, masks=np.asarray(masks), expressive=None if expressive is None else np.asarray(expressive),
        cfg=cfg, loss_cfg=loss_cfg, clip=clip, model_path=model_path, preview=preview,
        previous=None if previous is None else np.asarray(previous, dtype=np.float64), device=device, roll=roll,
        box=box,
    )  # fmt: skip
    return Job("imitate-keyframes", run, apply, title)


def _imitate_video(report: Reporter, cancel, *, masks, expressive, cfg, loss_cfg, clip, model_path, preview,
                   previous=None, device=None, roll=0.0, box=None):  # fmt: skip
    from studio.imitate.sequence import SequenceImitator
    from studio.imitate.still import Imitator

    with Imitator(None, model_path, loss_cfg, clip, device=device) as im, SequenceImitator(imitator=im) as seq:
        pv = PosePreview(im.hand, preview, roll=roll) if preview else None
        return imitate_keyframes(seq, masks, expressive, cfg, previous=previous, roll=roll,
                                 box_for=None if box is None else lambda k, done: box,
                                 progress=report.engine_progress(pv), cancel=cancel,
                                 best_pose=pv.pose if pv else None)  # fmt: skip


def imitate_keyframes(
    seq: Any,
    masks: np.ndarray,
    expressive: np.ndarray | None,
    cfg: SequenceConfig | None,
    *,
    previous: np.ndarray | None = None,
    roll: float = 0.0,
    box_for: Any = None,
    progress: Any = None,
    cancel: threading.Event | None = None,
    best_pose: Any = None,
) -> Any:
    """The one imitation of keyframe targets ``masks (K, S, S)`` (and ``expressive``) with a
    :class:`~studio.imitate.sequence.SequenceImitator` already holding its models → its ``SequenceResult``: the
    body of :func:`imitate_video_job`, and of a spread project run's workers (:mod:`studio.project.run_spread`).
    ``roll`` rad: the mount's roll (every shadow and loss is the rolled mount's against the targets as they are);
    ``box_for(k, done)`` as ``SequenceImitator.imitate``."""
    from dataclasses import replace

    from studio.imitate.config import CPU_SEQUENCE

    cfg = cfg or CPU_SEQUENCE
    if expressive is None and cfg.expressive:
        cfg = replace(cfg, expressive=False)  # no masks given: the base loss alone
    return seq.imitate(masks, expressive, progress, cancel, cfg=cfg, best_pose=best_pose, previous=previous,
                       box_for=box_for, roll=roll)  # fmt: skip


def refine_together_job(
    masks: np.ndarray,
    expressive: np.ndarray | None,
    theta: np.ndarray,
    *,
    pairs: dict,
    boxes: list,
    cfg: SequenceConfig,
    loss_cfg: LossConfig | None = None,
    clip: Any = None,
    model_path: Path | None = None,
    previous: np.ndarray | None = None,
    device: str | None = None,
    roll: float = 0.0,
    preview: int = 64,
    ids: list[int] | None = None,
    apply: Apply = None,
    title: str = "keyframes together",
) -> Job:
    """Keyframes already posed at ``theta (K, 21)`` rad (show order; targets ``masks (K, S, S)``, ``expressive``
    alike or None) refined together within their reach on the show's clock → ``(scores, JointResult)``
    (:func:`studio.imitate.together.refine_show`: after posing them last to first too with ``cfg.joint.both_orders``,
    stages "last to first: keyframe k/K: ..."; ``pairs`` ``(i, j) → (21,)`` rad by index, ``boxes[k]``
    ``(lower, upper)`` or None from the poses outside them, ``previous (21,)`` the pose before the first); stage
    "together"; a cancel keeps the best poses found before it (the job still ends cancelled, nothing applied). While
    they are posed again, events carry ``preview``² shadows of the best pose so far (0: none); ``ids``: the
    keyframes' own ids, for their stage names ("last to first: keyframe 7 (3 of 3): search")."""
    run = functools.partial(
        _together, masks=np.asarray(masks), expressive=None if expressive is None else np.asarray(expressive),
        theta=np.asarray(theta, dtype=np.float64), pairs=pairs, boxes=list(boxes), cfg=cfg, loss_cfg=loss_cfg,
        clip=clip, model_path=model_path, previous=None if previous is None else np.asarray(previous, np.float64),
        device=device, roll=roll, preview=preview, ids=None if ids is None else list(ids),
    )  # fmt: skip
    return Job("imitate-together", run, apply, title)


def _together(report: Reporter, cancel, *, masks, expressive, theta, pairs, boxes, cfg, loss_cfg, clip, model_path,
              previous, device, roll, preview, ids):  # fmt: skip
    from studio.imitate.sequence import SequenceImitator
    from studio.imitate.still import Imitator
    from studio.imitate.together import Stretch, refine_show

    stretch = Stretch(masks, expressive, pairs, lambda k: boxes[k], previous, roll, ids)
    with Imitator(None, model_path, loss_cfg, clip, device=device) as im, SequenceImitator(imitator=im) as seq:
        pv = PosePreview(im.hand, preview, roll=roll) if preview else None
        got = refine_show(seq, stretch, theta, cfg, report.engine_progress(pv), cancel, pv.pose if pv else None)
        report.check()
        return got


def choose_roll_job(
    masks: np.ndarray,
    *,
    loss_cfg: LossConfig | None = None,
    model_path: Path | None = None,
    apply: Apply = None,
    title: str = "mount roll",
) -> Job:
    """``--roll auto``: the one mount roll for the keyframe targets ``masks (K, S, S)`` (chosen on their outlines)
    → :class:`~studio.imitate.roll_search.RollChoice` (:func:`~studio.imitate.roll_search.choose_roll`, on the
    retrieval index of the model's resolution; stage "index" while it is built, once per machine, then "roll")."""
    run = functools.partial(_choose_roll, masks=np.asarray(masks), loss_cfg=loss_cfg, model_path=model_path)
    return Job("choose-roll", run, apply, title)


def check_roll_job(
    masks: np.ndarray, deg: float, *, loss_cfg: LossConfig | None = None, model_path: Path | None = None,
    apply: Apply = None, title: str = "mount roll check",
) -> Job:  # fmt: skip
    """A roll the artist set (``deg`` degrees): the keyframe targets ``masks (K, S, S)`` it casts clearly worse than a
    roll of their own would → ``[Apart]`` (:func:`~studio.imitate.roll_search.check_roll`; stages as
    :func:`choose_roll_job`'s)."""
    run = functools.partial(_choose_roll, masks=np.asarray(masks), loss_cfg=loss_cfg, model_path=model_path, deg=deg)
    return Job("check-roll", run, apply, title)


def _choose_roll(report: Reporter, cancel, *, masks, loss_cfg, model_path, deg=None):
    from studio.imitate.still import Imitator

    with Imitator(None, model_path, loss_cfg, None) as im:
        progress = report.engine_progress()
        if deg is None:
            got = im.choose_roll(masks, progress=progress, cancel=cancel)
        else:
            got = im.check_roll(masks, deg, progress=progress, cancel=cancel)
        report.check()
        return got


@dataclass
class PlannedShow:
    """What a plan job returns: the show and the planner's checks (plain data; the Ruckig trajectory stays in the
    worker, since it does not pickle)."""

    show: Show  # the timed, validated show
    home_added: bool  # a rest pose was prepended at t = 0
    collision_checks: int  # poses checked along the timed trajectory
    max_jerk_ratio: float  # worst |jerk| / limit over the show (≤ 1)


def plan_job(
    keyframes: Keyframes, *, cfg: PlanConfig | None = None, show_title: str | None = None, apply: Apply = None,
    title: str = "plan",
) -> Job:  # fmt: skip
    """Plan a show through ``keyframes`` (:func:`studio.motion.plan.plan_show`) → :class:`PlannedShow`.

    Stages "keyframes", "path", "timing" and "show" (:func:`~studio.motion.plan.plan_show`). The job's cancel event
    goes to ``plan_show``, which raises :class:`~studio.motion.errors.PlanCancelled` within one collision query or
    timing round: the job ends ``cancelled`` and applies nothing. A keyframe in collision or a segment too fast fails
    the job with the planner's typed error."""
    return Job("plan", functools.partial(_plan, keyframes=keyframes, cfg=cfg, show_title=show_title), apply, title)


def _plan(report: Reporter, cancel, *, keyframes, cfg, show_title) -> PlannedShow:
    from studio.motion.plan import plan_show
    from studio.sim.hand import load_hand

    report.check()
    r = plan_show(load_hand(), keyframes, cfg, progress=report.engine_progress(), title=show_title, cancel=cancel)
    return PlannedShow(r.show, r.home_added, r.collision_checks, r.max_jerk_ratio)
