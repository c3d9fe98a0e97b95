"""The foundation's typed errors, the one progress and cancel protocol of every long engine call, and counts in words.

Errors: each one a user can meet says what is wrong and what to do (the CLI reports a :class:`StudioError` as one
clear line, no traceback). Every message counts in words that agree with the number (:func:`count`: ``1 keyframe``,
``3 keyframes``, never ``keyframe(s)``; the CLI, the engine and the panels alike).

Progress (DESIGN §5.11): a long call (segmentation, the retrieval index build, the block sweep, the gradient search,
the refinement, a keyframe or a sequence of them, planning a show, playing it, collecting or training, a table over
many targets) takes ``progress: ProgressFn | None`` and ``cancel: threading.Event | None``. It reports typed
:class:`Progress` events; setting ``cancel`` makes it return within about a second with what it finished (each
call's docstring says what that is), or raises :class:`Cancelled` when it has nothing worth returning.

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

IRREGULAR = {"was": "were", "is": "are", "it": "them", "collides": "collide", "belongs": "belong"}  # not word + "s"


def plural(word: str, n: int) -> str:
    """``word`` for one, its plural for any other count (``keyframe`` → ``keyframes``, ``was`` → ``were``)."""
    if n == 1:
        return word
    if word in IRREGULAR:
        return IRREGULAR[word]
    return word + ("es" if word.endswith(("s", "x", "ch", "sh")) else "s")


def count(n: int, word: str) -> str:
    """``1 keyframe``, ``0 keyframes``, ``200,000 poses``: the number and the word that agrees with it."""
    return f"{n:,} {plural(word, n)}"


class StudioError(Exception):
    """Base class of every error the CLI reports as one clear line (no traceback)."""


class Cancelled(StudioError):
    """A long engine call stopped because its cancel event was set and has nothing worth returning (planning a show:
    half a plan is no show). Calls that can return what they finished return it instead; a job that ends with this
    is reported ``cancelled``, not failed."""


class ShardError(StudioError):
    """A dataset shard is missing, truncated, corrupt, or was made for another hand or rig."""


class ClosedError(StudioError):
    """An object was used after ``close()`` (or the end of its ``with`` block) released what it held."""


class TargetError(StudioError):
    """A target or footage file is missing, unreadable, not an image or video, or holds no usable shadow."""


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
