"""The command line's side of a project run (``imitate``, ``imitate-video``, ``project run``, ``demo``): bars, Ctrl-C,
and the lines a run prints, in the command line's words.

- :func:`run_with_bars`: runs an engine call on a fresh job queue (its jobs on ``--threads``) with
  :class:`~studio.jobs.bars.TqdmBars` (one bar per job stage and per engine stage on stderr; none with
  ``--quiet``), the first Ctrl-C cancelling it;
- :func:`print_run`: the late transitions, then the run's message with what to type about it;
- :func:`advice`: what the command line says after an engine error a user can meet (the engine's messages name
  no flags, DESIGN §5.14).
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from studio.learn.threads import DEFAULT_THREADS

T = TypeVar("T")


def run_with_bars(
    run: Callable[..., T], quiet: bool, *subscribers: Callable[[Any], None], threads: int = DEFAULT_THREADS
) -> T:
    """``run(queue=, cancel=, on_job=, progress=)`` with tqdm bars and Ctrl-C → cancel (module doc); its result.
    ``subscribers`` get the queue's job events too (a review's job progress); the jobs' torch work runs on
    ``threads`` CPU threads (``--threads``; 0: torch's default)."""
    from tqdm import tqdm

    from studio.cli.progress import ctrl_c_cancels
    from studio.jobs import JobQueue, TqdmBars

    bars = TqdmBars(disable=quiet)
    queue = JobQueue(threads=threads or None)
    unsubscribes = [queue.subscribe(f) for f in (bars, *subscribers)]

    def on_job(job: Any, what: str) -> None:
        if not quiet:
            tqdm.write(f"job #{job.id}: {what}", file=sys.stderr)

    try:
        with ctrl_c_cancels() as cancel:
            return run(queue=queue, cancel=cancel, on_job=on_job, progress=bars)
    finally:
        for unsubscribe in unsubscribes:
            unsubscribe()
        bars.close()
        queue.close()


def print_late(late: list[dict], stretched: bool) -> None:
    """One line per transition too fast for the servos at the show's clock: frames, needed vs given seconds
    (``stretched``: ``--allow-late`` made them slower, so later keyframes shift)."""
    for t in late:
        origin = "home" if t["from_frame"] is None else f"frame {t['from_frame']}"
        print(f"{'late' if stretched else 'too fast'}: {origin} → frame {t['to_frame']} "
              f"({t['t_start']:.3f} → {t['t_end']:.3f} s) needs {t['needed_s']:.3f} s, the video gives "
              f"{t['given_s']:.3f} s{'; stretched, later keyframes shift' if stretched else ''}")  # fmt: skip


def print_run(report: Any) -> None:
    """The human lines of a run (a :class:`~studio.project.run.RunReport`): the late transitions, then what happened
    (on stderr when it did not end with a show) and, when transitions were too fast, what to pass."""
    from studio.project.summary import apart_text
    from studio.sim.roll import mount_text

    print_late(report.late, stretched=report.show is not None)
    print(f"mount: {mount_text(report.roll)}")
    if report.apart:
        print(f"  {apart_text(report.apart)}")
    message = report.message
    if report.too_fast:
        message += " (pass --allow-late to stretch them)"
    print(message, file=sys.stderr if report.error or report.cancelled or report.show is None else sys.stdout)


ADVICE: dict[str, str | Callable[[BaseException], str]] = {  # an engine error's class name → what the command line
    # adds to its one line (a string, or a function of the error)
    "SegmentationNeeded": " (pass --box X,Y,W,H or --first-mask PNG)",
    "SourceChanged": " (project run --reload-sources re-reads it)",
    "SourceMissing": lambda e: " (put it back, or: shadow-studio project relink NAME.shadow {} NEW_PATH)".format(
        getattr(e, "source", "SOURCE")
    ),
    "ProjectLocked": " (project run --wait SECONDS waits for it)",
    "ProjectChanged": " (run the command again: it reads the project afresh)",
    "OtherProject": " (--fresh starts over, or choose another --out)",
    "ResultsNeeded": " (shadow-studio project run optimises them)",
    "ShowNeeded": " (shadow-studio project run plans it)",
    "SegmentTooFastError": " (pass --allow-late to stretch them)",
    "NotAProject": lambda e: _new_project(getattr(e, "file", None)),
    "ShowError": lambda e: _project_show(getattr(e, "path", None)),
    "CalibrationMissing": " (shadow-studio calibrate makes one)",
    "MountMismatch": " (shadow-studio calibrate --roll DEG --start CAL --out CAL records it)",
    "CheckpointError": lambda e: " (shadow-studio {} --out PATH makes one)".format(
        "train-inverse" if getattr(e, "kind", None) == "inverse" else "train"
    ),
    "ShowForAnotherHand": " (pass --force to play it anyway)",
    "EStopResetFailed": "",
    "EStopLatched": " (shadow-studio estop --reset clears it; in jog, type reset)",
    "ServoTimeout": " (shadow-studio scan --port PORT lists the servos that answer)",
    "ChecksumError": " (shadow-studio scan --port PORT lists the servos that answer)",
    "UnexpectedReply": " (shadow-studio scan --port PORT lists the servos that answer)",
}


def _new_project(source: str | None) -> str:
    """How to make the project that was not there: from the file given instead of it, when one was."""
    if source is None:
        return " (shadow-studio project new makes one)"
    return f" (make one from it: shadow-studio project new {Path(source).stem}.shadow --source {source})"


def _project_show(path: str | None) -> str:
    """How to get the show of a project folder given where a show file goes ("" for anything else)."""
    from studio.project.project_format import DOC

    if path is None or not (Path(path) / DOC).is_file():
        return ""
    return f" (a project: shadow-studio project export {path} --out show.json writes its show)"


def advice(error: BaseException) -> str:
    """What to type about an engine error, in the command line's words ("" when there is nothing to add). Read by
    class name, so that a failing verb imports nothing more to say it."""
    said = next((ADVICE[c.__name__] for c in type(error).__mro__ if c.__name__ in ADVICE), "")
    return said(error) if callable(said) else said
