"""A project's frame images on ``show_time`` too, so a viewer that follows the show player shows the frame played.

:func:`log_show_frames` logs, at the show time where each frame starts to play (a stretched late transition moves
the frames after it: the project passes those times), the frame's target, its expressive mask, its RGB source and
its keyframe's rendered and self-model shadows: the same images as on ``frame`` (:mod:`studio.review.frames`), whose
entities they share. Rerun shows the latest row at or before the time in view, so a row logged for an earlier plan
at a time the new plan has no row at would show that plan's frame in between: every time logged before is logged
again with the frame the show plays then now (the times logged are returned for the next call).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import rerun as rr

from studio.review.blueprint import EXPRESSIVE, RENDERED, SELF_MODEL, SOURCE, TARGET, set_time
from studio.review.frames import KeyframeReview
from studio.review.sheets import display, tint
from studio.review.video_review import frame_at


def log_show_frames(
    rec: rr.RecordingStream,
    targets: np.ndarray,
    expressive: np.ndarray,
    keyframes: Sequence[KeyframeReview],
    which: np.ndarray,
    show_times: np.ndarray,
    sources: Sequence[np.ndarray | None] | None = None,
    before: np.ndarray | None = None,
) -> np.ndarray:
    """The images of frames ``targets (N, S, S)`` (``expressive (N, S, S)``, ``sources``: RGB or None per frame),
    whose keyframe is ``keyframes[which[k]]`` (-1: none), on ``show_time`` at ``show_times (N,)`` s, where each frame
    starts to play, and again at the times ``before`` (the last call's return) with the frame played then now
    (module doc). Returns the times logged, ascending."""
    show_times = np.asarray(show_times, dtype=float)
    if show_times.shape != (len(targets),):
        raise ValueError(f"{len(targets)} frames need as many show times, not {show_times.shape}")
    order = np.argsort(show_times, kind="stable")
    at = np.union1d(show_times, np.zeros(0) if before is None else np.asarray(before, dtype=float))
    for t, k in zip(at, order[frame_at(show_times[order], at)]):
        set_time(rec, show_time=float(t))
        rec.log(TARGET, rr.Image(display(targets[k])))
        rec.log(EXPRESSIVE, rr.Image(tint(targets[k], expressive[k])))
        source = None if sources is None else sources[k]
        rec.log(SOURCE, rr.Clear(recursive=False) if source is None else rr.Image(np.asarray(source)))
        kf = keyframes[which[k]] if which[k] >= 0 else None
        for entity, image in ((RENDERED, None if kf is None else kf.shadow),
                              (SELF_MODEL, None if kf is None else kf.self_model)):  # fmt: skip
            rec.log(entity, rr.Clear(recursive=False) if image is None else rr.Image(display(image)))
    rec.reset_time()
    return at
