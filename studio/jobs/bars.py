"""The CLI's face of job events: one tqdm bar per job stage (a subscriber; the widgets consume the same events).

    queue.subscribe(TqdmBars())          # bars on stderr, a new one when the stage changes, closed at the end

Bars show ``#id kind: stage``, ``step/total`` and the best loss; the final event closes the job's bar. tqdm limits
its own redraws (``mininterval``), so a bar costs little on the job's thread.
"""

from __future__ import annotations

import math
from typing import IO

from studio.jobs.events import JobEvent, JobState

QUIET_STAGES = ("start", "apply")  # stages that open no bar of their own


class TqdmBars:
    """Subscriber drawing the jobs' progress with tqdm on ``file`` (stderr by default)."""

    def __init__(self, file: IO[str] | None = None, disable: bool = False, mininterval: float = 0.1):
        self.file = file  # where bars go (None: stderr)
        self.disable = disable  # draw nothing (``--quiet``), keep the bookkeeping
        self.mininterval = mininterval  # s between redraws of one bar
        self._bars: dict[int, object] = {}
        self._stage: dict[int, str] = {}

    def __call__(self, event: JobEvent) -> None:
        from tqdm import tqdm

        jid = event.job_id
        if event.final:
            self.close(jid)
            return
        if event.state != JobState.RUNNING or event.stage in QUIET_STAGES:
            return
        bar = self._bars.get(jid)
        if bar is None or self._stage.get(jid) != event.stage:
            self.close(jid)
            bar = tqdm(
                total=event.total or None, desc=f"#{jid} {event.kind}: {event.stage}", unit="step",
                file=self.file, disable=self.disable, mininterval=self.mininterval, leave=False,
            )  # fmt: skip
            self._bars[jid], self._stage[jid] = bar, event.stage
        if event.step < bar.n:  # the stage starts over (refinement of the next candidate)
            bar.reset(total=event.total or None)
        elif event.total and bar.total != event.total:
            bar.total = event.total
        if event.step > bar.n:
            if not math.isnan(event.best):
                bar.set_postfix_str(f"best {event.best:.4f}", refresh=False)
            bar.update(event.step - bar.n)

    def close(self, job_id: int | None = None) -> None:
        """Close one job's bar (or every bar)."""
        for jid in [job_id] if job_id is not None else list(self._bars):
            bar = self._bars.pop(jid, None)
            self._stage.pop(jid, None)
            if bar is not None:
                bar.close()
