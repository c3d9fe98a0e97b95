"""The one tqdm face of progress, for jobs and for engine calls run directly (the widgets consume the same events).

    queue.subscribe(TqdmBars())          # a job queue's events: bars on stderr, closed at each job's end
    with TqdmBars() as bars:             # an engine call on the command line: its Progress events, job 0
        collect(out, cfg, progress=bars)

:class:`TqdmBars` takes a :class:`~studio.jobs.events.JobEvent` or a bare :class:`~studio.errors.Progress` (an
engine call run directly, drawn as job 0). Each job has one bar per stage: ``#id kind: stage`` (a bare stream: the
stage alone), ``step/total``, then the best loss when finite and the item (a target's name) when set. A stage that
starts while another is unfinished opens beneath it (a table's targets over the target's search), a finished one is
replaced by the next; a stage reported again closes the bars opened beneath it. ``disable`` (``--quiet``) draws
nothing. tqdm limits its own redraws (``mininterval``), so a bar costs little on the reporting thread.
"""

from __future__ import annotations

import math
import threading
from typing import IO, Any

from studio.errors import Progress
from studio.jobs.events import JobEvent, JobState

QUIET_STAGES = ("start", "apply")  # job stages that open no bar of their own
BARE = 0  # the job number of a bare Progress stream


class TqdmBars:
    """Draws job events and bare :class:`~studio.errors.Progress` events with tqdm on ``file`` (module doc).

    A :data:`~studio.errors.ProgressFn` and a job queue subscriber alike; ``with`` closes every bar on the way out
    (close it before printing a line of your own)."""

    def __init__(
        self, file: IO[str] | None = None, disable: bool = False, mininterval: float = 0.1, leave: bool = False,
        depth: int = 2,
    ):  # fmt: skip
        self.file = file  # where bars go (None: stderr)
        self.disable = disable  # draw nothing (``--quiet``)
        self.mininterval = mininterval  # s between redraws of one bar
        self.leave = leave  # a job's outermost bar stays on screen when closed (inner bars never do)
        self.depth = depth  # bars open at once per job, at most (an outer stage and the stage under it)
        self._bars: dict[int, list[tuple[str, Any]]] = {}  # job → [(stage, tqdm bar)], outermost first
        self._lock = threading.Lock()  # events come from the queue's thread and the caller's alike

    def __call__(self, event: JobEvent | Progress) -> None:
        if self.disable:
            return
        if isinstance(event, Progress):
            jid, desc = BARE, event.stage
        else:
            if event.final:
                self.close(event.job_id)
                return
            if event.state != JobState.RUNNING or event.stage in QUIET_STAGES:
                return
            jid, desc = event.job_id, f"#{event.job_id} {event.kind}: {event.stage}"
        with self._lock:
            self._draw(self._bar(jid, event.stage, desc, event.total), event)

    def _bar(self, jid: int, stage: str, desc: str, total: int) -> Any:
        """The bar of ``stage`` in job ``jid``: its own (closing the ones beneath it), or a new one (module doc)."""
        from tqdm import tqdm

        stack = self._bars.setdefault(jid, [])
        for i, (s, bar) in enumerate(stack):
            if s == stage:
                for _, inner in stack[i + 1 :]:
                    inner.close()
                del stack[i + 1 :]
                return bar
        while stack and (len(stack) >= self.depth or _finished(stack[-1][1])):
            stack.pop()[1].close()
        bar = tqdm(
            total=total or None, desc=desc, unit="step", file=self.file, mininterval=self.mininterval,
            leave=self.leave and not stack,
        )  # fmt: skip
        stack.append((stage, bar))
        return bar

    @staticmethod
    def _draw(bar: Any, event: JobEvent | Progress) -> None:
        total = event.total or None
        if event.step < bar.n:  # the stage starts over (refinement of the next candidate)
            bar.reset(total=total)
        elif bar.total != total:
            bar.total = total
        shown = ([f"best {event.best:.4f}"] if math.isfinite(event.best) else []) + ([event.item] if event.item else [])
        postfix = ", ".join(shown)
        changed = postfix != bar.postfix
        bar.set_postfix_str(postfix, refresh=False)
        if event.step > bar.n:
            bar.update(event.step - bar.n)
        elif changed:
            bar.refresh()

    def close(self, job_id: int | None = None) -> None:
        """Close one job's bars (job 0: the bare stream's), or every bar."""
        with self._lock:
            for jid in [job_id] if job_id is not None else list(self._bars):
                for _, bar in reversed(self._bars.pop(jid, [])):
                    bar.close()

    def __enter__(self) -> TqdmBars:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _finished(bar: Any) -> bool:
    """The bar reached its total (a stage done: the next stage replaces it)."""
    return bool(bar.total) and bar.n >= bar.total
