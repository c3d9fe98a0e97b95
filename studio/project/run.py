"""Bring a project up to date: optimise every keyframe whose result is missing or stale, then plan its show. What
``project run``, ``imitate``, ``imitate-video``, ``demo`` and the notebook's Optimise tab all run.

    report = project.run(RunConfig(allow_late=True), cancel=event)       # or run_project(project, ...)
    report.optimised, report.skipped, report.show, report.late, report.transitions

Keyframes run one job each on the project's queue (:func:`~.jobs.queue_for`), in first-appearance order, so a
finished keyframe is saved the moment it completes (one edit each) and its progress shows as its own job (its
keyframe ids travel on the job: ``job.meta["keyframes"]``, its place in the run: ``job.meta["of"]``). In
``sequential`` mode a keyframe continues from the keyframe before it in its source (its current result's pose: the
search starts there and the temporal term holds to it), exactly as one sequence imitation would; the first
keyframe of a source (a still's only one) is searched from scratch. A keyframe whose result is current is skipped,
never recomputed, unless the run names it (``keyframes=[...]``: the artist asked for those); the show is re-planned
only when it is missing or stale, at the show clock of :meth:`Project.show_timing`.

Nothing is applied from a job that fails or is cancelled: a cancel (``cancel`` set, Ctrl-C in the CLI) stops within
a second and leaves the project as it was except for the keyframes that completed before it. A run refuses to start
when a source is missing (moved or deleted) or changed on disk since it was read, since the keyframes' inputs would
no longer be what the project shows: the :class:`~studio.project.state.ProjectError` says so.
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

from studio.errors import ProgressFn, count, plural
from studio.evaluate.worker_models import ModelRecipe
from studio.imitate.config import CPU_SEQUENCE, SequenceConfig
from studio.imitate.transitions import TransitionConfig
from studio.jobs.engine import _plan
from studio.jobs.events import JobState, Reporter
from studio.jobs.job import Job
from studio.jobs.queue import JobQueue
from studio.learn.fanout import FanoutConfig
from studio.motion.plan import PlanConfig
from studio.project.jobs import queue_for, roll_check_job, roll_job, video_job
from studio.project.run_report import RunReport, TooFast, late_transitions
from studio.project.run_spread import keyframe_config, place_in_source, run_spread, source_keyframes
from studio.project.run_together import refine_stretches, refines_together, to_refine_together
from studio.project.show_timing import ShowLayout, keyframe_box, seams_out_of_reach
from studio.project.state import ProjectError
from studio.project.status import ProjectHandle, check_sources
from studio.sim.roll import roll_deg

if TYPE_CHECKING:
    from studio.motion.plan import Keyframes


RUN_JOB_KINDS = ("choose-roll", "imitate-keyframes", "imitate-together", "plan")  # the kinds of job a run submits


@dataclass(frozen=True)
class RunConfig:
    """What a project run does (every face's: ``project run``'s flags, the notebook's settings)."""

    sequence: SequenceConfig = CPU_SEQUENCE  # search/refine budgets and mode of every keyframe (CPU preset)
    plan: PlanConfig = field(default_factory=PlanConfig)  # the show's planner (timing.allow_late: see allow_late)
    allow_late: bool = False  # stretch transitions too fast for the servos (later keyframes shift) instead of no show
    layout: ShowLayout = field(default_factory=ShowLayout)  # how the sources share the show clock
    transitions: TransitionConfig = field(default_factory=TransitionConfig)  # the transition-success test
    device: str | None = None  # where the self-model and CLIP run: "cpu", "cuda" (None: CUDA when present)
    fanout: FanoutConfig = field(default_factory=FanoutConfig)  # keyframes on workers, sources side by side

    @property
    def spread(self) -> bool:
        """The keyframes run on workers, the sources side by side (:mod:`studio.project.run_spread`)."""
        return self.fanout.workers > 1 or bool(self.fanout.ray)


def _plan_or_late(report: Reporter, cancel, *, keyframes, cfg, show_title):
    from studio.motion.errors import SegmentTooFastError

    home = bool(keyframes.times[0] > 0)
    try:
        return _plan(report, cancel, keyframes=keyframes, cfg=cfg, show_title=show_title)
    except SegmentTooFastError as e:
        return TooFast(e.segments, home, str(e))


def plan_project_job(project: ProjectHandle, keyframes: Keyframes, cfg: PlanConfig) -> Job:
    """Plan the project's show (``project.set_show`` on completion; its media the first source when that is a video);
    a transition too fast without ``allow_late`` ends the job ``done`` with a :class:`TooFast` result, nothing
    applied."""
    from studio.motion.show import MediaRef

    inputs = project.show_inputs()
    first = project.state.sources[0]  # a video that opens the show plays beside it from show time 0
    media = None if first.kind == "still" else MediaRef(first.absolute, "video", 0.0)

    roll = project.mount.roll

    def apply(r: Any) -> None:
        if not isinstance(r, TooFast):
            project.set_show(replace(r.show, media=media, roll=roll), inputs=inputs)

    run = functools.partial(_plan_or_late, keyframes=keyframes, cfg=cfg, show_title=project.state.title)
    return Job("plan", run, apply, "show")


def run_project(
    project: ProjectHandle,
    cfg: RunConfig | None = None,
    clip: Any = None,
    queue: JobQueue | None = None,
    cancel: threading.Event | None = None,
    model_path: Any = None,
    on_job: Callable[[Job, str], None] | None = None,
    keyframes: list[int] | None = None,
    plan: bool = True,
    wait: float = 0.0,
    progress: ProgressFn | None = None,
    models: ModelRecipe | None = None,
) -> RunReport:
    """Optimise every missing or stale keyframe of ``project`` (or exactly the ids in ``keyframes``, current or not),
    then, with ``plan``, plan its show when missing or stale (module doc) → :class:`RunReport`. ``clip``: a CLIP
    encoder for the CLIP terms (None: off); ``queue``: where the jobs run (default the project's,
    :func:`queue_for`; subscribe bars to it); ``cancel``: stops the run (within 1 s); ``on_job(job, what)``: told
    of each job as it is submitted (``what``: one line, "keyframe 3 (2 of 5)"). Raises SourceMissing or
    SourceChanged before any work, and a ProjectError naming an id that is not a keyframe. The project's write lock
    is held throughout (another writer: :class:`~studio.project.lock.ProjectLocked` before any work, or after
    waiting up to ``wait`` s). With ``cfg.spread`` the keyframes run on workers, the sources side
    by side (:mod:`~studio.project.run_spread`: the same poses), reporting to ``progress``; ``models``: what each worker
    loads (default: ``model_path`` and CLIP as found, on ``cfg.device``)."""
    check_sources(project)
    cfg = cfg or RunConfig()
    if cfg.spread and models is None:
        from studio.imitate.still import DEFAULT_MODEL

        models = ModelRecipe(str(model_path or DEFAULT_MODEL), cfg.device, use_clip=clip is not None)
    with project.writing("project run", wait):
        return _run(project, cfg, clip, queue, cancel, model_path, on_job, keyframes, plan, progress, models)


def _run(project: ProjectHandle, cfg: RunConfig, clip, queue, cancel, model_path, on_job, keyframes, plan,
         progress=None, models=None) -> RunReport:  # fmt: skip
    t0 = time.perf_counter()
    queue = queue or queue_for(project)
    report = RunReport(str(project.path))
    ids = [kf.id for kf in project.keyframes]
    if keyframes is None:
        pending = list(project.status().pending)
    else:
        unknown = sorted(set(keyframes) - set(ids))
        if unknown:
            raise ProjectError(f"{project.path}: no keyframe {unknown}; the keyframes are {ids}")
        pending = [k for k in ids if k in set(keyframes)]
    mount = project.mount
    if mount.auto and not mount.chosen and (pending or project.results):
        job = queue.submit(roll_job(project, model_path=model_path))
        if on_job is not None:
            on_job(job, f"the mount roll for {count(len(ids), 'keyframe')}")
        state = job.follow(cancel)
        if state != JobState.DONE or not project.mount.chosen:
            report.cancelled, report.error = state == JobState.CANCELLED, job.error
            report.message = "choosing the mount roll " + ("cancelled" if report.cancelled else f"failed: {job.error}")
            return report.finish(project, cfg.transitions, t0)
        report.roll_chosen = True
        if keyframes is None:
            pending = list(project.status().pending)  # a new roll makes the keyframes of another one stale
    elif mount.measurable(len(ids)) and len(pending) == len(ids):
        job = queue.submit(roll_check_job(project, model_path=model_path))  # a roll set, every pose to find anew
        if on_job is not None:
            on_job(job, f"what the mount roll {roll_deg(project.mount.roll):g}° costs {count(len(ids), 'keyframe')}")
        if job.follow(cancel) == JobState.CANCELLED:
            report.cancelled, report.message = True, "measuring the mount roll cancelled"
            return report.finish(project, cfg.transitions, t0)
    report.skipped = [k for k in ids if k not in pending]
    status = project.status()
    settled = {k for k in ids if k in project.results and k not in status.stale and k not in pending}
    together = to_refine_together(project, pending) if refines_together(cfg.sequence) else frozenset()
    if cfg.spread and pending:
        if not run_spread(project, pending, settled, cfg.sequence, cfg.layout, cfg.plan.limits, cfg.fanout, clip,
                          models, progress, cancel, report, together):  # fmt: skip
            return report.finish(project, cfg.transitions, t0)
    elif not _optimise(project, cfg, clip, queue, cancel, model_path, on_job, pending, settled, report, together):
        return report.finish(project, cfg.transitions, t0)
    # a move between two sources too fast for the servos: one of its keyframes again, within reach of its neighbours
    seq, seams = cfg.sequence, []
    if seq.keep_clock:  # the paper's way (no clock) leaves late moves to the planner, as within a source
        seams = seams_out_of_reach(project.state, report.optimised, cfg.layout, cfg.plan.limits, seq.clock_margin)
    if seams:
        project.optimise_again(seams)  # stale till done: a run stopped before it leaves them to the next
        done = _optimise(project, cfg, clip, queue, cancel, model_path, on_job, seams, set(ids), report, together,
                         " again: its move to or from another source was too fast for the servos")  # fmt: skip
        report.optimised = list(dict.fromkeys(report.optimised))
        if not done:
            return report.finish(project, cfg.transitions, t0)
    if refines_together(seq) and not refine_stretches(project, cfg, clip, queue, cancel, model_path, on_job, report):
        return report.finish(project, cfg.transitions, t0)
    if not plan:
        report.message = f"optimised {count(len(report.optimised), 'keyframe')}"
        return report.finish(project, cfg.transitions, t0)
    status = project.status()
    if status.missing or status.stale:
        done = count(len(report.optimised), "keyframe")
        report.message = (
            f"optimised {done}; the show needs every keyframe current (still to optimise: {list(status.pending)})"
        )
        return report.finish(project, cfg.transitions, t0)
    colliding = [k for k in ids if not project.results[k].collision_free]
    if colliding:
        n = len(colliding)
        them = "it" if n == 1 else "them"
        report.message = (f"no show: the pose of {plural('keyframe', n)} {colliding} {plural('collides', n)} with "
                          f"itself; optimise {them} again with refinement on, then plan the show")  # fmt: skip
        return report.finish(project, cfg.transitions, t0)
    if project.show is not None and not status.show_stale:
        report.show, report.message = "current", report.nothing_done()
        report.late = late_transitions(project.show_timing(cfg.layout), project.show)
        return report.finish(project, cfg.transitions, t0)
    timing = project.show_timing(cfg.layout)
    plan_cfg = replace(cfg.plan, timing=replace(cfg.plan.timing, allow_late=cfg.allow_late))
    job = queue.submit(plan_project_job(project, timing.keyframes, plan_cfg))
    if on_job is not None:
        on_job(job, f"the show ({len(timing.keyframes.times)} planner keyframes, {timing.end_s:.2f} s)")
    state = job.follow(cancel)
    if state != JobState.DONE:
        report.cancelled, report.error = state == JobState.CANCELLED, job.error
        report.message = "planning the show " + ("cancelled" if report.cancelled else f"failed: {job.error}")
        return report.finish(project, cfg.transitions, t0)
    if isinstance(job.result, TooFast):
        report.late = timing.late_transitions(job.result.segments, job.result.home_added)
        report.too_fast = True
        report.message = (
            f"no show: {count(len(report.late), 'transition')} too fast for the servos at the show's clock; allow "
            "late transitions to stretch them (the show then runs longer), or give those keyframes more time"
        )
        return report.finish(project, cfg.transitions, t0)
    planned = job.result
    report.late = late_transitions(timing, planned.show)
    report.show = "planned"
    stretched = f", {count(len(report.late), 'late transition')} stretched" if report.late else ""
    resumed = [k for k in report.refined if k not in report.optimised]  # a stopped run posed them, did not refine
    again = f", refined {count(len(resumed), 'keyframe')} together that a stopped run had posed" if resumed else ""
    report.message = (f"optimised {count(len(report.optimised), 'keyframe')}, skipped {len(report.skipped)} current"
                      f"{again}; planned a {planned.show.duration:.2f} s show{stretched}")  # fmt: skip
    return report.finish(project, cfg.transitions, t0)


def _optimise(project, cfg, clip, queue, cancel, model_path, on_job, pending, settled, report, together,
              why="") -> bool:  # fmt: skip
    """The pending keyframes one job each on the queue, in order; False when one failed or was cancelled. A
    keyframe's reach box counts ``settled`` and its own source's keyframes finished before it (run_spread's rule);
    those in ``together`` are saved as awaiting their refinement together."""
    seq = cfg.sequence
    for n, k in enumerate(pending):
        pos, before = place_in_source(project, k)
        previous = None
        if seq.mode == "sequential" and before is not None:
            previous = project.results[before].theta(_joint_names())
        box = None
        if seq.keep_clock:  # within the servos' reach of the posed keyframes at the show's clock
            same = set(source_keyframes(project, k)) & set(report.optimised)
            box = keyframe_box(project.state, project.status(), k, seq.clock_margin, cfg.layout, cfg.plan.limits,
                               posed=settled | same)  # fmt: skip
        owed = "together" if k in together else ""  # the run refines it with its neighbours after
        job = video_job(project, [k], cfg=keyframe_config(seq, pos), clip=clip, previous=previous,
                        model_path=model_path, device=cfg.device, box=box, awaits=owed)  # fmt: skip
        job.meta["of"] = (n + 1, len(pending))
        queue.submit(job)
        if on_job is not None:
            on_job(job, f"keyframe {k} ({n + 1} of {len(pending)}){why}")
        state = job.follow(cancel)
        if state == JobState.DONE:
            report.optimised.append(k)
            continue
        report.cancelled, report.error = state == JobState.CANCELLED, job.error
        what = "cancelled" if report.cancelled else f"failed ({job.error})"
        report.message = f"keyframe {k} {what}; {count(len(report.optimised), 'keyframe')} finished and saved before it"
        return False
    return True


class Running:
    """``Project.run`` (mixed into :class:`~studio.project.project.Project`): :func:`run_project` on itself, the one
    function (``project.run(cfg, clip=..., keyframes=...)`` is ``run_project(project, cfg, clip=..., ...)``)."""

    run = run_project


def _joint_names() -> list[str]:
    from studio.sim.hand import load_hand

    return load_hand().joint_names
