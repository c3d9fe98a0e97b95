"""How the panels write numbers for the artist: times, losses and shares, the stages of a job, late transitions.

One place, so every panel writes a time as ``0.80 s`` (never ``0.7999999999999999``); a count is
:func:`studio.errors.count` (``1 keyframe`` / ``5 keyframes``, never ``1 keyframes`` nor ``keyframe(s)``).
"""

from __future__ import annotations

import math

from studio.errors import count

ALLOW_LATE = "allow late transitions"  # the box that stretches moves too fast for the servos (Optimise, Export)


def seconds(t: float | None, places: int = 2) -> str:
    """A time as the artist reads it: ``0.80 s`` (``places`` decimals); ``-`` for None or not a number."""
    if t is None or not math.isfinite(float(t)):
        return "-"
    return f"{float(t):.{places}f} s"


def span(t0: float, t1: float) -> str:
    """A time range: ``0.40–0.80 s``, or one time when both ends are the same to the hundredth."""
    a, b = seconds(t0), seconds(t1)
    return a if a == b else f"{a[:-2]}–{b}"


def loss(value: float | None) -> str:
    """A loss to three decimals (``-`` when there is none)."""
    if value is None or not math.isfinite(float(value)):
        return "-"
    return f"{float(value):.3f}"


def stage(name: str, total: int = 0, item: str = "") -> str:
    """A job's stage as the artist reads it: ``index`` (its total: poses) is the retrieval index being built, once
    per machine, ``compile`` the kernels compiling, once per install (the ``item`` of either, when there is one, says
    that another process builds it and this one waits: :data:`studio.imitate.index_cache.WAITING`,
    :data:`studio.imitate.kernels.WAITING`), ``together`` a show's keyframes refined together; a prefix
    (``keyframe 2/5: index``) is kept."""
    head, _, last = name.rpartition(": ")
    waits = f": {item}" if item else ""
    if last == "index":
        size = count(total, "pose") if total else "poses"
        last = f"building the retrieval index of {size} (first use only, cached){waits}"
    elif last == "compile":  # studio.imitate.kernels
        last = f"compiling the renderer's and the losses' kernels (first run after this install only){waits}"
    elif last == "together":  # studio.imitate.joint_refine
        last = "refining the keyframes together, within their reach on the show's clock"
    return f"{head}: {last}" if head else last


BAR_LABELS = {"index": "retrieval index (first use)", "compile": "compiling kernels (first run)",
              "together": "keyframes together"}  # stages whose name alone says little  # fmt: skip


def bar_label(name: str) -> str:
    """A progress bar's short label for a stage: a one-off stage (the index's build, the kernels' compile) and the
    keyframes refined together in words, any other stage as it is."""
    return BAR_LABELS.get(name.rpartition(": ")[2], name)


def late_lines(late: list[dict]) -> list[str]:
    """The late transitions of a show (``RunReport.late`` / ``VideoTiming.late_transitions``: frames, keyframes,
    needed versus given seconds), one line each: ``frame 3 → frame 4 (k1 → k2) at 0.50 s: needs 0.62 s, given
    0.25 s``."""
    out = []
    for t in late:
        a = "home" if t.get("from_frame") is None else f"frame {t['from_frame']}"
        ka = "home" if t.get("from_keyframe") is None else f"k{t['from_keyframe']}"
        out.append(
            f"{a} → frame {t['to_frame']} ({ka} → k{t['to_keyframe']}) at {seconds(t['t_start'])}: "
            f"needs {seconds(t['needed_s'])}, given {seconds(t['given_s'])}"
        )
    return out
