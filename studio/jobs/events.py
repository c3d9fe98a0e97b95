"""What a background job tells the world (plain data), and the reporter an engine call talks to.

A job's life is a stream of :class:`JobEvent`: one ``queued``, one ``running`` (stage "start"), progress events
while it runs (state ``running``: stage, step of total, best loss so far, now and then a small preview of the
current best shadow), and one final event (``done``, ``failed`` with its :class:`JobError`, or ``cancelled``).
Both faces consume the same events: the CLI through :class:`~studio.jobs.bars.TqdmBars`, the widgets by
subscribing or polling (:class:`~studio.jobs.queue.JobQueue`).

Inside the worker the engine call gets a :class:`Reporter` and a cancel event: the reporter is the engine call's
:data:`~studio.errors.ProgressFn` (``report(Progress(...))``, or :meth:`Reporter.engine_progress` to add live
previews), each :class:`~studio.errors.Progress` becoming one progress event; :class:`PosePreview` turns the
engine's ``best_pose(θ)`` hook into a ≤ 64² shadow at most ~10 times a second.
"""

from __future__ import annotations

import enum
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from studio.errors import Cancelled, Progress, ProgressFn, StudioError


class JobState(str, enum.Enum):
    """Where a job is in its life; the last three are final."""

    QUEUED = "queued"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"

    @property
    def finished(self) -> bool:
        return self in (JobState.DONE, JobState.FAILED, JobState.CANCELLED)


class JobCancelled(Cancelled):
    """Raised inside a job's worker (by :meth:`Reporter.check`) to stop an engine call that has no cancel event of
    its own; the job ends ``cancelled`` and applies nothing (as it does when the engine raises any
    :class:`~studio.errors.Cancelled`, e.g. a cancelled plan)."""


class WorkerDied(StudioError):
    """The worker process of a job ended without an answer (killed, out of memory, or a crash in native code); the
    job failed and applied nothing: run it again (a fresh worker is started)."""


@dataclass(frozen=True)
class JobError:
    """Why a job failed: the exception's type and message (one line for the user) and its traceback (for -v)."""

    type: str  # exception class name, e.g. "TargetError"
    message: str  # str(exception)
    traceback: str  # the formatted traceback, from the worker

    def __str__(self) -> str:
        return f"{self.type}: {self.message}"


@dataclass(frozen=True)
class JobEvent:
    """One thing that happened to a job (plain data, safe to keep or send to another thread)."""

    job_id: int  # the queue's number for the job (1, 2, ... in submission order)
    kind: str  # what runs: "imitate-keyframe", "imitate-keyframes", "plan", "play", or a caller's name
    state: JobState  # the job's state after this event
    stage: str  # the engine's stage ("search", "refine", "keyframe 2/3: search", "path", "play", ...)
    step: int  # progress within the stage [0, total]
    total: int  # steps in the stage (0 = unknown)
    best: float  # best loss so far (NaN where the stage has none)
    shadow: np.ndarray | None  # (H, W ≤ 64) uint8 preview of the current best shadow (1 = shadow); None: no new one
    elapsed: float  # seconds since the job started running (0 while queued)
    seq: int  # this event's number within its job: 0, 1, 2, ... in the order emitted
    error: JobError | None = None  # set on the final event of a failed job
    item: str = ""  # the item the engine works on when it goes over many (a target's name, "sequence · row"), else ""

    @property
    def fraction(self) -> float:
        """``step / total`` within the stage (NaN when the total is unknown)."""
        return self.step / self.total if self.total > 0 else math.nan

    @property
    def final(self) -> bool:
        return self.state.finished


Send = Callable[[tuple], None]  # worker → dispatcher message sink


class Reporter:
    """The progress sink an engine call gets in its worker, a :data:`~studio.errors.ProgressFn`: ``report(p)``
    with a :class:`~studio.errors.Progress` sends one progress event (``engine_progress(preview)`` adds the live
    shadow previews). Code that is not an engine call may still call ``report(stage, step, total, best, shadow)``.

    Calls are cheap (one tuple put on a queue). ``check()`` raises :class:`JobCancelled` once the job was cancelled:
    call it between stages of engine code that takes no cancel event.
    """

    def __init__(self, send: Send, cancel: threading.Event):
        self._send = send
        self.cancel = cancel  # the job's cancel event (threading.Event, or multiprocessing's in a process worker)

    def __call__(
        self, stage: str | Progress, step: int = 0, total: int = 0, best: float = math.nan,
        shadow: np.ndarray | None = None, item: str = "",
    ) -> None:  # fmt: skip
        if isinstance(stage, Progress):
            stage, step, total, best, item = stage.stage, stage.step, stage.total, stage.best, stage.item
        self._send(("progress", str(stage), int(step), int(total), float(best), shadow, str(item)))

    def check(self) -> None:
        """Raise :class:`JobCancelled` if the job was cancelled."""
        if self.cancel.is_set():
            raise JobCancelled("the job was cancelled")

    def engine_progress(self, preview: PosePreview | None = None) -> ProgressFn:
        """The engine call's ``progress`` (any long call: search, refine, sequence, plan, collect...): each
        :class:`~studio.errors.Progress` becomes a progress event, with ``preview``'s newest shadow when one is
        due."""

        def progress(p: Progress) -> None:
            self(p, shadow=preview.image() if preview is not None else None)

        return progress


class PosePreview:
    """Small shadow previews of the engine's current best pose, rendered at most ``max_hz`` times a second.

    ``pose(θ)`` (the engine's ``best_pose`` hook) only stores the pose; ``image()`` renders the newest stored pose
    at ``size``² when the last render is older than ``1/max_hz`` s and the pose changed, else returns None. The
    window is the rig's (the self-model's frame), so a preview lines up with the target framed at any resolution.
    """

    def __init__(self, hand=None, size: int = 64, max_hz: float = 10.0, roll: float = 0.0):
        from studio.sim.shadow import Rig, ShadowRenderer

        if not 8 <= size <= 64:
            raise ValueError(f"preview size must be 8–64 pixels, got {size}")
        self.renderer = ShadowRenderer(hand, Rig(resolution=size, roll=roll))  # as the mount rolled by roll rad casts
        self.period = 1.0 / max_hz
        self._theta: np.ndarray | None = None
        self._fresh = False
        self._last = -math.inf

    def pose(self, theta: np.ndarray) -> None:
        self._theta, self._fresh = np.asarray(theta, dtype=np.float64), True

    def image(self, force: bool = False) -> np.ndarray | None:
        """``(size, size)`` uint8 shadow of the newest pose, or None when nothing new is due."""
        now = time.monotonic()
        if self._theta is None or not self._fresh or (not force and now - self._last < self.period):
            return None
        self._fresh, self._last = False, now
        return self.renderer.render(self._theta[None], check=False)[0]


class EventPoller:
    """Events for a consumer that pulls (thread-safe): the newest ``maxlen`` are kept, older ones counted as dropped."""

    def __init__(self, maxlen: int = 10_000):
        self._events: deque[JobEvent] = deque()
        self._maxlen = maxlen
        self._cond = threading.Condition()
        self.dropped = 0  # events discarded because nobody polled for a while

    def put(self, event: JobEvent) -> None:
        with self._cond:
            if len(self._events) >= self._maxlen:
                self._events.popleft()
                self.dropped += 1
            self._events.append(event)
            self._cond.notify_all()

    def poll(self, timeout: float = 0.0) -> list[JobEvent]:
        """Every event since the last poll, oldest first; waits up to ``timeout`` s for one when there are none."""
        with self._cond:
            if not self._events and timeout > 0:
                self._cond.wait(timeout)
            out = list(self._events)
            self._events.clear()
        return out
