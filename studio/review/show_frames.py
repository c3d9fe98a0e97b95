"""A project's frame images on ``show_time`` too, so a viewer that follows the show player shows the frame played.

:func:`log_show_frames` logs, at the show time where each frame starts to play (a stretched late transition moves
the frames after it: the project passes those times), the frame's target, its expressive mask, its RGB source and
its keyframe's rendered and self-model shadows: the same images as on ``frame`` (:mod:`studio.review.frames`), whose
entities they share. Rerun shows the latest row at or before the time in view, so a row logged for an earlier plan
at a time the new plan has no row at would show that plan's frame in between: every time logged before is logged
again with the frame the show plays then now. What was logged is kept in a :class:`ShowFramesLogged` (the times,
and a digest of what the images came from, so a project logged again unchanged logs nothing here).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import rerun as rr

from studio.review.blueprint import EXPRESSIVE, RENDERED, SELF_MODEL, SOURCE, TARGET, set_time
from studio.review.frames import KeyframeReview
from studio.review.series import digest
from studio.review.sheets import display, tint
from studio.review.video_review import frame_at


@dataclass
class ShowFramesLogged:
    """What :func:`log_show_frames` logged on one recording so far (it updates it)."""

    times: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (M,) s every show time a frame was logged at
    key: bytes | None = None  # the digest of what the images logged last were made from


def log_show_frames(
    rec: rr.RecordingStream,
    targets: np.ndarray,
    expressive: np.ndarray,
    keyframes: Sequence[KeyframeReview],
    which: np.ndarray,
    show_times: np.ndarray,
    sources: Sequence[np.ndarray | None] | None = None,
    logged: ShowFramesLogged | None = None,
) -> ShowFramesLogged:
    """The images of frames ``targets (N, S, S)`` (``expressive (N, S, S)``, ``sources``: RGB or None per frame),
    whose keyframe is ``keyframes[which[k]]`` (-1: none), on ``show_time`` at ``show_times (N,)`` s, where each frame
    starts to play, and again at the times ``logged`` holds (an earlier call's) with the frame played then now
    (module doc). Nothing is logged when the images and times are those ``logged`` says were logged last. Returns
    ``logged`` (a new record when None), updated."""
    logged = ShowFramesLogged() if logged is None else logged
    show_times = np.asarray(show_times, dtype=float)
    if show_times.shape != (len(targets),):
        raise ValueError(f"{len(targets)} frames need as many show times, not {show_times.shape}")
    key = digest(targets, expressive, np.asarray(which), show_times, *[kf.shadow for kf in keyframes],
                 *[kf.self_model for kf in keyframes], *(sources or []))  # fmt: skip
    if key == logged.key:
        return logged
    order = np.argsort(show_times, kind="stable")
    at = np.union1d(show_times, logged.times)
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
    logged.times, logged.key = at, key
    return logged
