"""The one progress protocol of every long engine call (DESIGN §5.11), part of the foundation.

A long call (segmentation, the retrieval index build, the block sweep, the gradient search, the refinement, a
keyframe or a sequence of them, planning a show, playing it, collecting or training, a table over many targets)
takes ``progress: ProgressFn | None`` and ``cancel: threading.Event | None``. It reports typed
:class:`Progress` events; setting ``cancel`` makes it return within about a second with what it finished (each
call's docstring says what that is).

    def segment(frames, progress=None, cancel=None):
        for i, frame in enumerate(frames):
            if stopped(cancel):
                return done
            ...
            report(progress, "segment", i + 1, len(frames))

Both faces consume the same events: the command line draws them with :class:`studio.jobs.bars.TqdmBars`, a
background job forwards them as :class:`studio.jobs.events.JobEvent` (which the notebook's panels draw).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Progress:
    """One report of a long engine call (plain data)."""

    stage: str  # what runs now: "segment", "index", "retrieve", "sweep", "search", "refine", "keyframe 2/5: search"
    step: int = 0  # work done within the stage [0, total]
    total: int = 0  # work in the stage (0: unknown)
    best: float = math.nan  # the best loss so far (NaN where the stage has none)
    item: str = ""  # the item the call works on when it goes over many (a target's name), else ""

    @property
    def fraction(self) -> float:
        """``step / total`` (NaN when the total is unknown)."""
        return self.step / self.total if self.total > 0 else math.nan


ProgressFn = Callable[[Progress], None]  # what a long engine call reports to


def report(
    progress: ProgressFn | None, stage: str, step: int = 0, total: int = 0, best: float = math.nan, item: str = ""
) -> None:
    """Send one :class:`Progress` to ``progress`` (nothing when it is None)."""
    if progress is not None:
        progress(Progress(stage, int(step), int(total), float(best), item))


def staged(progress: ProgressFn | None, prefix: str, item: str | None = None) -> ProgressFn | None:
    """``progress`` with every stage named ``prefix + stage`` ("keyframe 2/5: " + "search") and, given ``item``, every
    event's item set to it (the run a table's step belongs to); None stays None."""
    if progress is None:
        return None

    def forward(p: Progress) -> None:
        progress(Progress(prefix + p.stage, p.step, p.total, p.best, p.item if item is None else item))

    return forward


def stopped(cancel: threading.Event | None) -> bool:
    """Whether ``cancel`` is set (False for None)."""
    return cancel is not None and cancel.is_set()
