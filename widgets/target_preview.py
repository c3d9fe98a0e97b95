"""What the Targets panel previews for one frame: the threshold alone, and the mask the project would store after
its cleanup, both decided in source pixels exactly as the engine decides them, then cropped to the preview square.

The polarity (bright shape on dark, or dark on bright) is the project's: :func:`~studio.targets.images.
detect_polarity` on every sampled frame of the source in source pixels (a still: its one image), as
:func:`~studio.targets.video.load_video` and :func:`~studio.targets.images.mask_from_grey` find it, never on the
padded square the artist sees, whose black bars would read as a dark backdrop. The stored mask is the engine's own
function (:func:`~studio.targets.video.frame_mask` for footage, :func:`~studio.targets.images.mask_from_grey` for a
still), run with the slider's level (None: Otsu).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import cv2
import numpy as np

from studio.errors import TargetError
from studio.targets.images import TargetConfig, crop_square, detect_polarity, mask_from_grey, shadowness, square_mask
from studio.targets.video import VideoConfig, frame_mask


@dataclass
class FramePreview:
    """One frame as the Targets panel shows it, every image ``(side, side)`` in the preview square."""

    grey: np.ndarray  # uint8 grey levels of the frame
    level: float  # the shadowness level the threshold preview used (Otsu's when Otsu is on)
    mask: np.ndarray  # uint8 {0, 1}: shadowness above ``level``, nothing else
    stored: np.ndarray | None  # uint8 {0, 1}: what the project stores after its cleanup; None when it keeps nothing
    note: str  # one line on the stored mask ("" when there is nothing to say)


def source_polarity(frames: np.ndarray, configured: str = "auto") -> str:
    """The polarity of a source whose sampled grey frames are ``frames (N, H, W)`` (source pixels): the
    ``configured`` one, else the project's rule on all of them."""
    return configured if configured != "auto" else detect_polarity(np.asarray(frames))


def square(image: np.ndarray, box: tuple[int, int, int, int], side: int, mask: bool = False) -> np.ndarray:
    """``image (H, W)`` inside ``box (x, y, w, h)`` (outside: 0) at ``side²`` uint8: grey levels, or with ``mask``
    a {0, 1} mask thresholded at half coverage (the raw threshold's preview; :func:`square_mask` frames a mask as the
    project stores it)."""
    out = crop_square(np.asarray(image, np.float32), box, side)
    return (out >= 0.5).astype(np.uint8) if mask else np.clip(out, 0, 255).astype(np.uint8)


def frame_preview(
    grey: np.ndarray,
    box: tuple[int, int, int, int],
    side: int,
    polarity: str,
    level: float | None,
    footage: str,
    video: VideoConfig,
    still: TargetConfig,
    stored: np.ndarray | None = None,
    first: Callable[[np.ndarray, float, np.ndarray], None] | None = None,
) -> FramePreview:
    """The preview of one frame ``grey (H, W)`` uint8 (source pixels) in ``box`` at ``side²`` (module doc).

    ``polarity``: the source's (:func:`source_polarity`); ``level``: the slider's shadowness level, None for Otsu;
    ``footage``: what the source is ("still", "shadow", "mask" or "segmented": the project's ``Source.footage``);
    ``stored``: for segmented footage, the project's mask of this frame ``(S, S)`` (its threshold does not apply);
    ``first(grey, level, mask)``: given the threshold alone as soon as it is known, before the cleanup (which takes
    seconds on a large photo)."""
    grey = np.asarray(grey, np.uint8)
    shade = shadowness(grey, polarity)
    shown = level
    if shown is None:
        shown, _ = cv2.threshold(shade, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    mask = (shade > shown).astype(np.uint8)
    grey_sq, mask_sq = square(grey, box, side), square(mask, box, side, mask=True)
    if first is not None:
        first(grey_sq, float(shown), mask_sq)
    note = ""
    kept: np.ndarray | None
    if footage == "segmented":
        kept = None if stored is None else cv2.resize(np.asarray(stored, np.uint8), (side, side),
                                                      interpolation=cv2.INTER_NEAREST)  # fmt: skip
        note = "segmented footage: the stored mask comes from segmentation, not the threshold"
    else:
        try:
            if footage == "still":
                full = mask_from_grey(grey, replace(still, polarity=polarity, threshold=level), "this frame")
            else:
                full = frame_mask(grey, footage or "shadow", polarity, replace(video, threshold=level), "this frame")
            kept = square_mask(full, box, side)  # as the project frames it (its holes kept, no others)
        except TargetError as e:
            kept, note = None, f"nothing would be stored for this frame: {str(e).removesuffix(': this frame')}"
    return FramePreview(grey_sq, float(shown), mask_sq, kept, note)
