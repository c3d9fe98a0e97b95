"""A job's progress on the ``opt_step`` timeline: :class:`JobProgressLog` subscribes to a job queue and draws every
job's best loss (its stages one after another, each job after the jobs before it) with its live best shadow, and its
start and end in the jobs' log."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import rerun as rr

from studio.review.blueprint import JOBS_LOG, LOSS, RENDERED, part, set_time
from studio.review.sheets import display


class JobProgressLog:
    """A job queue subscriber (``queue.subscribe(JobProgressLog(rec))``) drawing every job's progress on ``opt_step``.

    Takes any event with ``job_id, kind, state, stage, step, total, best, shadow, elapsed, error`` (a
    ``studio.project.jobs.JobEvent``). A job's stages follow one another on ``opt_step`` (a stage starts where the
    previous one ended), and a job starts one step after the furthest step any job before it reached, so scrubbing
    past a short job's end never lands in an earlier job's progress; its best loss goes to ``loss/<job>/<stage>``,
    its preview shadow to ``images/rendered``, its start and end to ``log/jobs``. ``names`` maps a job id to the
    name in its entity paths (default ``job<id>_<kind>``). Thread-safe for one queue (events arrive on its
    dispatcher thread)."""

    def __init__(self, rec: rr.RecordingStream, names: Mapping[int, str] | None = None):
        self.rec = rec
        self.names = dict(names or {})
        self._at: dict[int, tuple[str, int, int]] = {}  # job id → (stage, offset, last step)
        self._start = 0  # where the next new job starts on opt_step: one past the furthest step drawn

    def name(self, event: Any) -> str:
        return part(self.names.get(event.job_id) or f"job{event.job_id}_{event.kind}")

    def __call__(self, event: Any) -> None:
        state = getattr(event.state, "value", str(event.state))
        stage, offset, last = self._at.get(event.job_id, (event.stage, self._start, 0))
        if event.stage != stage or event.step < last:  # a new stage (or a stage starting over) follows on
            stage, offset = event.stage, offset + last
        self._at[event.job_id] = (stage, offset, event.step)
        self._start = max(self._start, offset + event.step + 1)
        set_time(self.rec, opt_step=offset + event.step)
        if state == "running" and event.stage == "start" or state in ("done", "failed", "cancelled"):
            self.rec.log(JOBS_LOG, _job_line(event, state))
        elif state == "running":
            if math.isfinite(event.best):
                self.rec.log(f"{LOSS}/{self.name(event)}/{part(event.stage)}", rr.Scalars(float(event.best)))
            if event.shadow is not None:
                self.rec.log(RENDERED, rr.Image(display(event.shadow)))
        self.rec.reset_time()


def _job_line(event: Any, state: str) -> rr.TextLog:
    what = f"job {event.job_id} {event.kind}"
    if state == "failed":
        return rr.TextLog(f"{what} failed after {event.elapsed:.1f} s: {event.error}", level="ERROR")
    if state == "cancelled":
        return rr.TextLog(f"{what} cancelled after {event.elapsed:.1f} s", level="WARN")
    if state == "done":
        return rr.TextLog(f"{what} done in {event.elapsed:.1f} s", level="INFO")
    return rr.TextLog(f"{what} started", level="INFO")
