"""A job: one unit of background work, what :class:`~studio.jobs.queue.JobQueue` numbers, runs and reports on.

    job = Job("imitate-keyframe", run, apply=lambda r: project.set_result(k, r), title="keyframe 3")
    queue.submit(job)
    job.follow(cancel)                                   # wait, cancelling it once ``cancel`` is set
    job.state, job.result, job.error, job.info()

``run(report, cancel) -> result`` runs in the queue's worker; ``apply(result)`` runs once, only on completion (the
queue's module doc). A job keeps its latest progress (stage, step, total, best, the preview shadow) for listings.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

from studio.jobs.events import JobError, JobState
from studio.jobs.workers import Run


class Job:
    """A unit of background work (module doc). Made by the caller or a factory; the queue numbers and runs it."""

    def __init__(
        self,
        kind: str,
        run: Run,
        apply: Callable[[Any], None] | None = None,
        title: str = "",
        meta: Mapping[str, Any] | None = None,
    ):
        self.kind = kind  # what runs ("imitate-keyframe", "imitate-keyframes", "plan", "play", ...)
        self.run = run  # run(report, cancel) -> result, called in the worker
        self.apply_fn = apply  # apply(result), called once on completion (None: nothing to apply)
        self.title = title  # one line for listings ("keyframe 3", "muybridge_horse.gif")
        self.meta = dict(meta or {})  # what the submitter attaches for its own use ({"keyframes": [3]}): plain data
        self.id = 0  # set by JobQueue.submit (1, 2, ...)
        self.state = JobState.QUEUED
        self.result: Any = None  # run's return value (done; cancelled when the engine returned a partial one)
        self.error: JobError | None = None  # why it failed
        self.applied = False  # apply ran to the end
        self.stage, self.step, self.total, self.best, self.item = "", 0, 0, math.nan, ""  # the latest progress
        self.shadow = None  # the latest (H, W) uint8 preview of the current best shadow
        self.started: float | None = None  # time.monotonic() when it started running
        self.ended: float | None = None  # ... and when its final event was emitted
        self._seq = 0
        self._lock = threading.RLock()
        self._done = threading.Event()
        self._cancel = threading.Event()
        self._cancel_at: float | None = None
        self._applying = False
        self._queue: Any = None  # the JobQueue that took it (set by submit): a queued job cancelled finishes there
        self._runner = None

    @property
    def elapsed(self) -> float:
        """Seconds running so far (or in all, once finished); 0 while queued."""
        if self.started is None:
            return 0.0
        return (self.ended if self.ended is not None else time.monotonic()) - self.started

    @property
    def finished(self) -> bool:
        return self.state.finished

    def cancel(self) -> bool:
        """Ask the job to stop; False when it had already finished or is applying its result (too late). A queued
        job is cancelled at once."""
        with self._lock:
            if self.state.finished or self._applying:
                return False
            if self._cancel.is_set():
                return True
            self._cancel.set()
            self._cancel_at = time.monotonic()
            if self.state == JobState.QUEUED and self._queue is not None:
                self._queue._finish(self, JobState.CANCELLED)
            elif self._runner is not None:
                self._runner.cancel()
        return True

    def wait(self, timeout: float | None = None) -> JobState:
        """Block until the job finished (or ``timeout`` s passed); returns its state."""
        self._done.wait(timeout)
        return self.state

    def follow(self, cancel: threading.Event | None) -> JobState:
        """Wait until the job finished and every subscriber was told so (its final event delivered: a run that
        follows its jobs reports after the panels drew them), cancelling it once ``cancel`` is set (looked at every
        0.1 s; then up to 2 s for it to stop); returns its state."""
        while not self._done.is_set():
            if cancel is not None and cancel.is_set():
                self.cancel()
                return self.wait(2.0)
            self.wait(0.1)
        return self.state

    def info(self) -> dict:
        """One row of a listing (plain data)."""
        return {
            "id": self.id, "kind": self.kind, "title": self.title, "state": self.state.value, "stage": self.stage,
            "step": self.step, "total": self.total, "best": self.best, "elapsed": round(self.elapsed, 3),
            "error": None if self.error is None else str(self.error),
        }  # fmt: skip

    def __repr__(self) -> str:
        return f"Job(#{self.id} {self.kind} {self.title!r} {self.state.value})"
