"""A project run spread over workers (``project run --workers N`` / ``--ray``): one keyframe per item of a
:func:`studio.learn.fanout.fan_out`, the sources side by side.

A source's pending keyframes form a chain: in ``sequential`` mode each continues from the keyframe before it in
its source, so a chain goes out one keyframe at a time (the next as a follow-up of the one before it, whichever
worker is free), while the chains of the sources run side by side. Each worker holds one
:class:`~studio.imitate.sequence.SequenceImitator` (the self-model, CLIP and retrieval index loaded once) and runs
every keyframe through :func:`studio.jobs.engine.imitate_keyframes`, the body of the one-process run's keyframe
jobs, with the same seeds (:func:`keyframe_config`), the same pose before it and the same reach box on the show's
clock. The box counts the keyframes that were current when the run started and those of its own source finished
before it in this run (the one-process run counts the same ones), so where a keyframe runs never changes its pose:
the results equal :func:`~studio.project.run.run_project`'s in one process.

A keyframe's place in its source (:func:`source_keyframes`, :func:`place_in_source`) and the seeds that place gives it
(:func:`keyframe_config`) live here, for both runs.

Before any keyframe goes out, the driver makes sure this machine has what every worker's first search needs
(:func:`studio.project.jobs.search_ready`: the kernels compiled, the retrieval index built here, spread over the
same workers), so no worker compiles or builds its own.
The driver saves each keyframe (``project.set_result``, one edit) the moment it comes back, and progress counts
keyframes; ``cancel`` (Ctrl-C) stops the workers, and the project keeps every keyframe finished before it.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from studio.errors import ProgressFn, stopped
from studio.evaluate.worker_models import ModelRecipe
from studio.imitate.config import LossConfig, SequenceConfig
from studio.learn.fanout import FanoutConfig, fan_out
from studio.motion.limits import LimitsConfig

if TYPE_CHECKING:
    from studio.project.run_report import RunReport
    from studio.project.status import ProjectHandle

__all__ = [
    "Chain", "KeyframeStep", "KeyframeTask", "chains_of", "keyframe_config", "optimise_spread", "place_in_source",
    "run_spread", "source_keyframes",
]  # fmt: skip


def source_keyframes(project: ProjectHandle, k: int) -> list[int]:
    """The ids of the keyframes of keyframe ``k``'s source, first-appearance order (the whole video it is in)."""
    s = project.state
    src = s.frames[s.keyframe(k).representative].source
    return [kf.id for kf in s.keyframes if s.frames[kf.representative].source == src]


def place_in_source(project: ProjectHandle, k: int) -> tuple[int, int | None]:
    """``(position of keyframe k among its source's keyframes, id of the keyframe before it there or None)``: the
    seeds it gets (:func:`keyframe_config`) and the pose it continues from."""
    same = source_keyframes(project, k)
    pos = same.index(k)
    return pos, (same[pos - 1] if pos else None)


def keyframe_config(cfg: SequenceConfig, position: int) -> SequenceConfig:
    """``cfg`` with its seeds moved on by ``position`` (a keyframe's place in its source), as a whole sequence
    seeds its k-th keyframe."""
    return replace(cfg, first=replace(cfg.first, seed=cfg.first.seed + position),
                   next=replace(cfg.next, seed=cfg.next.seed + position))  # fmt: skip


@dataclass(frozen=True)
class Chain:
    """One source's pending keyframes, and what their runs need from the rest of the project (plain data; the
    driver's: a worker gets one :class:`KeyframeStep` of it at a time)."""

    source: str  # the source's file name (progress lines)
    ids: tuple[int, ...]  # pending keyframe ids, first-appearance order
    positions: tuple[int, ...]  # each one's place among its source's keyframes (its seeds)
    before: tuple[int | None, ...]  # the keyframe before each in its source (None: the source's first)
    masks: np.ndarray  # (n, S, S) uint8 targets
    expressive: np.ndarray  # (n, S, S) uint8 expressive masks
    clock: dict[tuple[int, int], float]  # the show clock's moves: (id, id) → s (show_timing.transition_times)
    poses: dict[int, np.ndarray]  # (21,) rad results of the keyframes outside the chain it refers to
    settled: frozenset[int]  # ids whose poses count for the reach box (current when the run started)

    def step(self, j: int, poses: dict[int, np.ndarray], boxed: set[int], sequential: bool) -> KeyframeStep:
        """Keyframe ``j`` of the chain as a worker runs it, given ``poses`` id → ``(21,)`` rad (the chain's outside
        poses and its keyframes finished so far) and ``boxed`` (the ids that count for the reach box)."""
        k, before = self.ids[j], self.before[j]
        return KeyframeStep(self.source, k, self.positions[j], self.masks[j], self.expressive[j],
                            poses[before] if sequential and before is not None else None, self.clock,
                            {n: p for n, p in poses.items() if n in boxed and n != k})  # fmt: skip


@dataclass(frozen=True)
class KeyframeStep:
    """One keyframe as a worker runs it (plain data): its target and the poses it continues from and keeps within
    reach of."""

    source: str  # its source's file name (progress lines)
    id: int  # the keyframe's id
    position: int  # its place among its source's keyframes (its seeds)
    mask: np.ndarray  # (S, S) uint8 target
    expressive: np.ndarray  # (S, S) uint8 expressive mask
    previous: np.ndarray | None  # (21,) rad the pose it continues from (sequential mode), None: from scratch
    clock: dict[tuple[int, int], float]  # the show clock's moves: (id, id) → s (show_timing.transition_times)
    posed: dict[int, np.ndarray]  # id → (21,) rad of the keyframes whose poses count for its reach box


@dataclass
class KeyframeTask:
    """What a worker needs to run keyframes (a :mod:`studio.learn.fanout` task): paths and configs, all picklable.
    ``task(step) → (the keyframe's id, its KeyframeResult)``."""

    models: ModelRecipe  # the self-model and CLIP each worker loads
    loss_cfg: LossConfig  # the project's loss weights (its expressive and temporal terms)
    seq: SequenceConfig  # the run's budgets and mode
    roll: float  # the mount roll, rad
    limits: LimitsConfig = field(default_factory=LimitsConfig)  # the servos' limits of the reach box
    _held: Any = field(default=None, init=False, repr=False, compare=False)  # the SequenceImitator once set up

    def __getstate__(self) -> dict:  # a worker gets the recipe, never this process's models
        return self.__dict__ | {"_held": None}

    def setup(self) -> None:
        from studio.imitate.sequence import SequenceImitator
        from studio.imitate.still import Imitator

        model, clip = self.models.load()
        self._held = SequenceImitator(imitator=Imitator(model, None, self.loss_cfg, clip))

    def close(self) -> None:
        if self._held is not None:
            self._held.imitator.close()
            self._held = None

    def __call__(self, step: KeyframeStep) -> tuple[int, Any]:
        from studio.jobs.engine import imitate_keyframes
        from studio.motion.limits import JointLimits
        from studio.motion.reach import reach_distances
        from studio.project.show_timing import reach_of

        if self._held is None:
            raise RuntimeError("KeyframeTask.setup() was not called")
        seq = self._held
        box = None
        if self.seq.keep_clock:
            lim = JointLimits.from_hand(seq.imitator.hand, self.limits)
            box = reach_of(reach_distances(step.clock, lim, self.seq.clock_margin).get(step.id, {}), step.posed, lim)
        result = imitate_keyframes(seq, step.mask[None], step.expressive[None],
                                   keyframe_config(self.seq, step.position), previous=step.previous, roll=self.roll,
                                   box_for=None if box is None else (lambda i, done: box))  # fmt: skip
        return step.id, result.keyframes[0]


def chains_of(project: ProjectHandle, pending: list[int], settled: set[int], layout: Any) -> list[Chain]:
    """The pending keyframes grouped by source, in first-appearance order (module doc)."""
    from studio.project.show_timing import transition_times
    from studio.sim.hand import load_hand

    s, names = project.state, load_hand().joint_names
    times = transition_times(s, layout)
    groups: dict[int, list[int]] = {}
    for k in pending:
        groups.setdefault(s.frames[s.keyframe(k).representative].source, []).append(k)
    chains = []
    for src, ids in groups.items():
        name = Path(s.sources[src].path).name
        places = [place_in_source(project, k) for k in ids]
        before = tuple(b for _, b in places)
        outside = {b for b in before if b is not None} | {n for pair in times for n in pair}
        poses = {n: s.results[n].theta(names) for n in outside - set(ids) if n in s.results}
        pairs = [project.keyframe_masks(k) for k in ids]
        chains.append(Chain(name, tuple(ids), tuple(pos for pos, _ in places), before,
                            np.stack([np.array(t) for t, _ in pairs]), np.stack([np.array(e) for _, e in pairs]),
                            times, poses, frozenset(settled & set(poses))))  # fmt: skip
    return chains


def optimise_spread(
    project: ProjectHandle,
    chains: list[Chain],
    task: KeyframeTask,
    fanout: FanoutConfig,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    saved: list[int] | None = None,
    together: frozenset[int] = frozenset(),
) -> list[int]:
    """Run ``chains`` on the workers ``fanout`` names, one keyframe at a time per chain, saving each keyframe as it
    comes back (its id appended to ``saved`` at once, so a worker's failure raised here leaves the list of what
    was kept; those in ``together`` saved as awaiting their refinement together); the ids saved, in the project's
    order. Stage "keyframes" as each finishes (item: its source)."""
    saved = [] if saved is None else saved
    sequential = task.seq.mode == "sequential"
    chain_of = {k: i for i, c in enumerate(chains) for k in c.ids}
    poses = [dict(c.poses) for c in chains]  # per chain: id → (21,) rad, its outside poses and those finished
    boxed = [set(c.settled) for c in chains]  # per chain: the ids whose poses count for the reach box

    def save(_: int, done: tuple[int, Any]) -> list[KeyframeStep]:
        k, kr = done
        project.set_result(k, kr.theta, kr.loss, kr.shadow, inputs=project.keyframe_inputs(k),
                           evaluation=kr.evaluation, collision_free=kr.collision_free,
                           seconds=kr.seconds, awaits="together" if k in together else "")  # fmt: skip
        saved.append(k)
        i = chain_of[k]
        poses[i][k] = kr.theta
        boxed[i].add(k)
        j = chains[i].ids.index(k) + 1  # the chain's next keyframe follows this one
        return [chains[i].step(j, poses[i], boxed[i], sequential)] if j < len(chains[i].ids) else []

    first = [c.step(0, poses[i], boxed[i], sequential) for i, c in enumerate(chains)]
    fan_out(task, first, fanout, progress, cancel, "keyframes", names=lambda step: step.source, on_result=save,
            total=sum(len(c.ids) for c in chains))  # fmt: skip
    return [kf.id for kf in project.keyframes if kf.id in set(saved)]


def run_spread(
    project: ProjectHandle, pending: list[int], settled: set[int], seq: SequenceConfig, layout: Any,
    limits: LimitsConfig, fanout: FanoutConfig, clip: Any, models: ModelRecipe, progress: ProgressFn | None,
    cancel: threading.Event | None, report: RunReport, together: frozenset[int] = frozenset(),
) -> bool:  # fmt: skip
    """A run's ``pending`` keyframes on workers (``fanout``), the sources side by side on the show's clock
    (``layout``, a :class:`~studio.project.show_timing.ShowLayout`), with the run's budgets ``seq`` and the servos'
    ``limits`` (module doc), into ``report``; False when a worker failed or the run was cancelled (the keyframes
    finished before it are saved; those in ``together`` as awaiting their refinement together)."""
    import traceback

    from studio.errors import count
    from studio.jobs.events import JobError
    from studio.project.jobs import project_loss, search_ready

    chains = chains_of(project, pending, settled, layout)
    task = KeyframeTask(models, project_loss(project, chains[0].masks.shape[-1], clip), seq, project.mount.roll, limits)
    try:
        if search_ready(Path(models.model), None, progress, cancel, fanout):  # before any worker starts
            report.optimised = optimise_spread(project, chains, task, fanout, progress, cancel, report.optimised,
                                               together)  # fmt: skip
    except Exception as e:  # a worker's failure, or no Ray to run on: one line, what was saved stays
        report.error = JobError(type(e).__name__, str(e), traceback.format_exc())
        done = count(len(report.optimised), "keyframe")
        report.message = f"the spread run stopped ({e}); {done} finished and saved"
        return False
    if stopped(cancel):
        report.cancelled = True
        report.message = f"cancelled; {count(len(report.optimised), 'keyframe')} finished and saved before it"
        return False
    return True
