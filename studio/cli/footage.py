"""A verb's video source: thresholded or mask footage as it is, or raw colour footage segmented from a first-frame
``--box X,Y,W,H`` or ``--first-mask PNG`` (:mod:`studio.targets.segment`), sampled at ``VideoConfig.hz``."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from studio.targets.video import VideoConfig

SEGMENT_MAX_HZ = 30.0  # raw footage is segmented at its source rate, at most this (or hz if higher)


def parse_box(text: str) -> tuple[int, int, int, int]:
    """``"x,y,w,h"`` (source pixels) → a box; an argparse error otherwise."""
    try:
        box = tuple(int(v) for v in text.split(","))
    except ValueError:
        box = ()
    if len(box) != 4 or box[2] < 1 or box[3] < 1 or box[0] < 0 or box[1] < 0:
        raise argparse.ArgumentTypeError(f"expected x,y,w,h in source pixels (w, h ≥ 1), got {text!r}")
    return box  # type: ignore[return-value]


def read_first_mask(path: Path) -> np.ndarray:
    """A first-frame mask PNG/JPEG → ``(H, W)`` uint8, 1 = object: pixels above grey 127, or any nonzero pixel when
    none is that bright (a palette mask such as DAVIS's dark-red object on black)."""
    from PIL import Image, UnidentifiedImageError

    from studio.errors import TargetError

    path = Path(path)
    if not path.is_file():
        raise TargetError(f"first mask not found: {path}")
    try:
        with Image.open(path) as im:
            grey = np.asarray(im.convert("L"))
    except (UnidentifiedImageError, OSError) as e:
        raise TargetError(f"the first mask is not a readable image ({e}): {path}") from None
    return (grey > 127 if grey.max() > 127 else grey > 0).astype(np.uint8)


def load_source(
    src: Path,
    cfg: VideoConfig,
    box: tuple[int, int, int, int] | None = None,
    first_mask: Path | None = None,
    progress=None,
    cancel=None,
):
    """The sampled video (:class:`~studio.targets.video.Video`): thresholded/mask footage as :func:`load_video`
    reads it, or colour footage segmented from ``box`` (x, y, w, h source px) or the ``first_mask`` file and framed
    by :func:`video_from_masks`. None when ``cancel`` stopped it. ``progress(stage, step, total)``.

    Segmentation propagates the object from frame to frame, so it runs on every source frame up to
    ``SEGMENT_MAX_HZ`` (neighbouring frames), and the sampled frames take their masks from it: on DAVIS blackswan
    from the first mask's box, segmenting only the 4 Hz samples scored J 0.37, every frame (24 fps) then sampled
    J 0.88."""
    from studio.targets.video import load_video, read_footage, video_from_masks

    if box is None and first_mask is None:
        video = load_video(src, cfg, progress, cancel)
        return None if video.cancelled else video
    from studio.targets.segment import segment_video

    first = None if first_mask is None else read_first_mask(first_mask)
    sampled = read_footage(src, cfg.hz, cfg.fps, cfg.max_bad_share, progress, cancel)
    dense = sampled
    if sampled.fps > cfg.hz and not sampled.cancelled:
        rate = min(sampled.fps, max(SEGMENT_MAX_HZ, cfg.hz))
        dense = read_footage(src, rate, cfg.fps, cfg.max_bad_share, progress, cancel)
    if dense.cancelled or sampled.cancelled:
        return None
    masks = segment_video(dense.frames, box=box, first_mask=first, progress=progress, cancel=cancel)
    if len(masks) < len(dense.frames):
        return None
    # each sampled frame's mask: the segmented frame with its source index (else the nearest in time)
    same = {int(i): k for k, i in enumerate(dense.frame_index)}
    nearest = [int(np.argmin(np.abs(dense.times - t))) for t in sampled.times]
    pick = [same.get(int(i), j) for i, j in zip(sampled.frame_index, nearest)]
    return video_from_masks(sampled, masks[pick], cfg, progress=progress)
