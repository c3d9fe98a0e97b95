"""Segmentation of raw colour footage with no downloaded weights: a first-frame box or mask → the object's mask
in every frame (DESIGN §4 "Video targets").

The classical method (``method="classical"``), at ``work_size`` (longest side, px), masks upsampled back:

1. **First frame.** A given mask is used as it is. From a box, the object is what moves unlike the background:
   the dense flow (DIS) to the next ``first_gaps`` frames against the homography of everything outside the box
   (:func:`~studio.targets.segment_cues.box_motion`) gives a motion cue inside it; starting from the pixels that
   move (Otsu), ``first_iterations`` rounds re-learn the object's and the background's colours and graph-cut the
   box with colour + local colour + motion evidence (outside the box is background). When nothing in the box
   moves apart (a static shot), OpenCV's GrabCut cuts the box (``first_grabcut_iterations`` rounds): on one frame of
   each of the four clips from its true box, J 0.53 → 0.66 against the colour rounds alone.
2. **Each later frame.** The previous mask is warped by the backward flow (DIS); a shape prior (its signed
   distance in units of ``shape_sigma`` × object size, size = √area), global colour histograms (anchored to the
   first frame, updated at ``model_update``), a bilateral-grid colour model of the warped guess and the motion cue
   (gated by its own reliability) add up to a unary term; pixels farther than ``far`` × size from the guess are
   background; the graph cut (contrast-sensitive, 8-connected) over the guess's box plus ``roi_margin`` decides;
   specks and pieces not overlapping the guess are dropped.
3. **Occlusion.** The object's size is remembered (√area, following growth at once and shrinking by ``size_decay``
   a frame): a mask smaller than that (the object partly hidden) is cut with room for the remembered size
   (``size_memory``), so it grows back when the occluder leaves. When the mask vanishes, or falls below
   ``redetect_below`` of the remembered area, the object is looked for again for ``search_frames`` frames: the
   pixels whose colour says object (the tracked colour models) near where it was last seen, the pieces with the
   most evidence; found, it is tracked on from there. On ``bench_segment.py``'s occlusion condition (a band of
   background sweeping across the object, hiding all of it for a moment on some clips) this took mean J over the
   five clips from 0.36 to 0.52, every other condition unchanged within 0.01.

Measured by ``benchmarks/bench_segment.py`` on DAVIS 2016 blackswan, camel, cows and dog (and bear, never tuned
on) from the first ground-truth mask's box and under harder conditions: the README gives the figures. A Segment
Anything model is used instead only when its package and a local checkpoint exist
(:mod:`studio.targets.segment_sam`; nothing is ever downloaded).
"""

from __future__ import annotations

import logging
import threading

import cv2
import numpy as np

from studio.errors import ProgressFn, TargetError, report, stopped
from studio.targets.segment_config import SegmentConfig
from studio.targets.segment_track import Tracker, WorkFrames, first_from_box

log = logging.getLogger(__name__)


def check_inputs(frames: np.ndarray, box, first_mask) -> tuple[tuple[int, int, int, int] | None, np.ndarray | None]:
    """Validate ``segment_video``'s inputs; returns the box clipped to the frame and the mask as uint8 {0, 1}."""
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.shape[0] == 0:
        raise TargetError(f"frames must be a non-empty (N, H, W, 3) RGB array, not an array of shape {frames.shape}")
    if frames.dtype != np.uint8:
        raise TargetError(f"frames must be uint8 RGB (0-255), not {frames.dtype}: convert them first")
    n, h, w = frames.shape[:3]
    if min(h, w) < 8:
        raise TargetError(f"frames of {w}×{h} px are too small to segment (at least 8×8)")
    if (box is None) == (first_mask is None):
        raise TargetError("give the object in the first frame as a box (x, y, w, h) or as a mask, one of the two")
    if first_mask is not None:
        mask = np.asarray(first_mask)
        if mask.shape != (h, w):
            raise TargetError(f"the first mask is {mask.shape[::-1]} but the frames are {w}×{h}: give an (H, W) mask")
        mask = (mask != 0).astype(np.uint8)
        if not mask.any():
            raise TargetError("the first mask is empty: paint the object (nonzero pixels) in the first frame")
        return None, mask
    try:
        x, y, bw, bh = (int(round(float(v))) for v in box)
    except (TypeError, ValueError):
        raise TargetError(f"the box must be four numbers (x, y, w, h) in pixels, not {box!r}") from None
    if bw < 2 or bh < 2:
        raise TargetError(f"the box {x, y, bw, bh} is empty: its width and height must be at least 2 px")
    x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + bw, w), min(y + bh, h)
    if x1 - x0 < 2 or y1 - y0 < 2:
        raise TargetError(
            f"the box (x, y, w, h) = {x, y, bw, bh} lies outside the {w}×{h} frame: draw it on the object"
        )
    if (x0, y0, x1, y1) != (x, y, x + bw, y + bh):
        log.warning("the box %s reaches outside the %d×%d frame: clipped", (x, y, bw, bh), w, h)
    if (x1 - x0) * (y1 - y0) > 0.98 * w * h:
        raise TargetError("the box covers the whole frame: draw it tightly around the object (it tells the background)")
    return (x0, y0, x1 - x0, y1 - y0), None


def segment_video(
    frames: np.ndarray,
    box: tuple[int, int, int, int] | None = None,
    first_mask: np.ndarray | None = None,
    cfg: SegmentConfig | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> np.ndarray:
    """The object's masks ``(N, H, W)`` uint8 {0, 1} in RGB ``frames`` ``(N, H, W, 3)`` uint8, given in frame 0 as a
    ``box`` (x, y, w, h) px or a ``first_mask`` ``(H, W)`` (nonzero = object), one of the two.

    Reports ``Progress("segment", step, total)`` after each frame; setting ``cancel`` stops within a frame and
    returns the masks of the frames done so far (fewer than N). Bad input raises :class:`TargetError` saying what to
    fix.
    """
    cfg = cfg or SegmentConfig()
    box, mask = check_inputs(frames, box, first_mask)
    frames = np.asarray(frames)
    if cfg.method != "classical":
        from studio.targets.segment_sam import segment_video_sam, unavailable, with_checkpoint

        cfg = with_checkpoint(cfg)
        reason = unavailable(cfg)
        if reason is None:
            return segment_video_sam(frames, box, mask, cfg, progress, cancel)
        if cfg.method == "sam":
            raise TargetError(reason)
        log.info("classical segmentation (%s)", reason)
    return _classical(frames, box, mask, cfg, progress, cancel)


def _classical(frames, box, mask, cfg: SegmentConfig, progress, cancel) -> np.ndarray:
    n, h_src, w_src = frames.shape[:3]
    work = WorkFrames(frames, cfg)
    w, h = work.size
    if mask is not None:
        cur = (cv2.resize(mask.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) >= 0.5).astype(np.uint8)
        if not cur.any():  # a tiny mask vanishes at the work size: keep its brightest pixel
            small = cv2.resize(mask.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
            cur.flat[int(np.argmax(small))] = 1
    else:
        cur = first_from_box(work, box, cfg)
    out = np.zeros((n, h_src, w_src), np.uint8)

    def emit(t: int, m: np.ndarray) -> None:
        if mask is not None and t == 0:
            out[0] = mask
        else:
            out[t] = cv2.resize(m.astype(np.float32), (w_src, h_src), interpolation=cv2.INTER_LINEAR) >= 0.5
        report(progress, "segment", t + 1, n)

    emit(0, cur)
    track = Tracker(work, cur, cfg)
    for t in range(1, n):
        if stopped(cancel):
            log.info("segmentation cancelled after %d of %d frames", t, n)
            return out[:t]
        cur = track.step(t, cur)
        emit(t, cur)
    return out
