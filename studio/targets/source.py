"""One way to read a source, for every face: what it is, its raw frames, and its targets.

A source is a still (an image file; a one-frame GIF), a video (a video file; an animated GIF or WebP) or a folder
of frames (:func:`source_kind`). What its frames hold (:attr:`Video.kind`) is found when it is read: a still,
binary masks (DAVIS ground truth), grey shadow footage, or raw colour footage that must be segmented.

:func:`open_source` reads any of them into a :class:`~studio.targets.video.Video`: masks ``(N, S, S)`` in one
square frame with their source times. A still is a one-frame video at t = 0 (``kind="still"``), framed around its
shadow as :func:`~studio.targets.images.load_target` frames it. Raw colour footage is segmented from the object's
first-frame box or mask (:mod:`studio.targets.segment`) *densely*: segmentation propagates the object from frame
to frame, so it runs on every source frame up to :data:`SEGMENT_MAX_HZ` and the sampled frames take their masks
from it (on DAVIS blackswan, from the first mask's box: segmenting only the 4 Hz samples scored J 0.37, every frame
at 24 fps then sampling J 0.88). Colour footage without a box or mask raises
:class:`~studio.targets.video.SegmentationNeeded`, which carries the sampled frames for the face to show.

:func:`raw_frames` reads the sampled RGB frames as they are (what a preview scrubs through, what a first-frame
box is drawn on).
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from studio.errors import ProgressFn, TargetError
from studio.targets.footage import Footage, read_footage
from studio.targets.images import IMAGE_SUFFIXES, TargetConfig, load_target, read_grey
from studio.targets.video import SegmentationNeeded, Video, VideoConfig, load_video, video_from_masks

SEGMENT_MAX_HZ = 30.0  # raw footage is segmented at its source rate, at most this (or at hz when that is higher)
KINDS = ("still", "video", "folder")  # what source_kind says a path is


def source_kind(path: str | Path) -> str:
    """``"folder"``, ``"still"`` (an image file with one frame) or ``"video"`` (anything else: a video file, an
    animated GIF or WebP)."""
    path = Path(path)
    if path.is_dir():
        return "folder"
    if path.suffix.lower() in IMAGE_SUFFIXES:
        try:
            with Image.open(path) as im:
                return "still" if getattr(im, "n_frames", 1) == 1 else "video"
        except OSError:
            return "still"  # load_target says what is wrong with it
    return "video"


def read_first_mask(path: str | Path) -> np.ndarray:
    """A first-frame mask image → ``(H, W)`` uint8, 1 = object: pixels above grey 127, or any nonzero pixel when none
    is that bright (a palette mask such as DAVIS's dark-red object on black). A TargetError for a bad file."""
    path = Path(path)
    if not path.is_file():
        raise TargetError(f"first mask not found: {path}")
    try:
        with Image.open(path) as im:
            grey = np.asarray(im.convert("L"))
    except (UnidentifiedImageError, OSError) as e:
        raise TargetError(f"the first mask is not a readable image ({e}): {path}") from None
    return (grey > 127 if grey.max() > 127 else grey > 0).astype(np.uint8)


def raw_frames(
    path: str | Path,
    video: VideoConfig | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> Footage:
    """The sampled RGB frames of a source as they are (a still: its one frame at t = 0), with their source times."""
    video = video or VideoConfig()
    path = Path(path)
    if source_kind(path) == "still":
        grey = read_grey(path)
        rgb = np.repeat(np.clip(grey, 0, 255).astype(np.uint8)[..., None], 3, axis=2)
        return Footage(path, 0.0, video.hz, 0.0, 1, np.zeros(1), np.zeros(1, np.int64), rgb[None])
    return read_footage(path, video.hz, video.fps, video.max_bad_share, progress, cancel)


def _still(path: Path, video: VideoConfig, still: TargetConfig) -> Video:
    mask = load_target(path, size=video.size, cfg=still)
    return Video(
        source=path, fps=0.0, hz=video.hz, times=np.zeros(1), frame_index=np.zeros(1, np.int64), masks=mask[None],
        frames=None, skipped=[], box=(0, 0, 0, 0), kind="still", duration_s=0.0, n_source=1,
        shadow_share=mask.reshape(1, -1).mean(axis=1),
    )  # fmt: skip


def _segmented(
    sampled: Footage, video: VideoConfig, box, first_mask, progress: ProgressFn | None, cancel: threading.Event | None
) -> Video:
    """Raw colour footage (its ``sampled`` frames) segmented densely (module doc), framed like any video."""
    from studio.targets.segment import segment_video

    path, dense = sampled.source, sampled
    if sampled.fps > video.hz and not sampled.cancelled:
        rate = min(sampled.fps, max(SEGMENT_MAX_HZ, video.hz))
        dense = read_footage(path, rate, video.fps, video.max_bad_share, progress, cancel)
    if dense.cancelled or sampled.cancelled:
        return _cancelled(sampled, video)
    masks = segment_video(dense.frames, box=box, first_mask=first_mask, progress=progress, cancel=cancel)
    if len(masks) < len(dense.frames):
        return _cancelled(sampled, video)
    # each sampled frame's mask: the segmented frame with its source index (else the nearest in time)
    same = {int(i): k for k, i in enumerate(dense.frame_index)}
    nearest = [int(np.argmin(np.abs(dense.times - t))) for t in sampled.times]
    pick = [same.get(int(i), j) for i, j in zip(sampled.frame_index, nearest)]
    return video_from_masks(sampled, masks[pick], video, progress=progress)


def _cancelled(footage: Footage, video: VideoConfig) -> Video:
    """What a cancelled read returns: no frames, ``cancelled=True``."""
    frames = np.zeros((0, video.size, video.size, 3), np.uint8) if video.keep_frames else None
    return Video(
        footage.source, footage.fps, footage.hz, np.zeros(0), np.zeros(0, np.int64),
        np.zeros((0, video.size, video.size), np.uint8), frames, list(footage.skipped), (0, 0, 0, 0),
        duration_s=footage.duration_s, n_source=footage.n_source, cancelled=True,
    )  # fmt: skip


def open_source(
    path: str | Path,
    video: VideoConfig | None = None,
    still: TargetConfig | None = None,
    box: tuple[int, int, int, int] | None = None,
    first_mask: np.ndarray | str | Path | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> Video:
    """Read any source into its targets (module doc): masks ``(N, S, S)`` uint8 (S = ``video.size``) in one square
    frame, source times, what the frames were (``kind``: "still", "mask", "shadow" or "segmented").

    ``video`` samples and binarises footage (:class:`~studio.targets.video.VideoConfig`), ``still`` binarises a
    still (:class:`~studio.targets.images.TargetConfig`); ``box`` ``(x, y, w, h)`` source pixels or ``first_mask``
    (an ``(H, W)`` array or an image file) give raw colour footage's object in its first frame (footage that is not
    in colour is binarised as it is). Progress events for
    the stages "read", "binarise", "segment" and "frame"; setting ``cancel`` returns a video flagged ``cancelled``
    (nothing framed when segmentation was cut short). Raises TargetError (a bad file; the message names it) and
    SegmentationNeeded (colour footage without a box or mask)."""
    path = Path(path)
    video, still = video or VideoConfig(), still or TargetConfig()
    if not path.exists():
        raise TargetError(f"source not found: {path}")
    if source_kind(path) == "still":
        return _still(path, video, still)
    if isinstance(first_mask, (str, Path)):
        first_mask = read_first_mask(first_mask)
    try:
        return load_video(path, video, progress, cancel)
    except SegmentationNeeded as e:
        if box is None and first_mask is None:
            raise
        return _segmented(e.footage, video, box, first_mask, progress, cancel)
