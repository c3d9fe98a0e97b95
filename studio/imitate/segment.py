"""Segmentation of raw colour footage with no downloaded weights: a first-frame box or mask → the object's mask
in every frame (DESIGN §4 "Video targets").

The classical method (``method="classical"``), at ``work_size`` (longest side, px), masks upsampled back:

1. **First frame.** A given mask is used as it is. From a box, the object is what moves unlike the background:
   the dense flow (DIS) to the next ``first_gaps`` frames against the homography of everything outside the box
   (:func:`~studio.imitate.segment_cues.box_motion`) gives a motion cue inside it; starting from the pixels that
   move (Otsu), ``first_iterations`` rounds re-learn the object's and the background's colours and graph-cut the
   box with colour + local colour + motion evidence (outside the box is background). When nothing in the box
   moves apart (a static shot), the box alone starts it, GrabCut-like.
2. **Each later frame.** The previous mask is warped by the backward flow (DIS); a shape prior (its signed
   distance in units of ``shape_sigma`` × object size, size = √area), global colour histograms (anchored to the
   first frame, updated at ``model_update``), a bilateral-grid colour model of the warped guess and the motion cue
   (gated by its own reliability) add up to a unary term; pixels farther than ``far`` × size from the guess are
   background; the graph cut (contrast-sensitive, 8-connected) over the guess's box plus ``roi_margin`` decides;
   specks and pieces not overlapping the guess are dropped.

Measured by ``benchmarks/bench_segment.py`` on DAVIS 2016 blackswan, camel, cows and dog from the first ground-truth
mask's box: see that file's docstring for the figures. A Segment Anything model is used instead only when its
package and a local checkpoint exist (:mod:`studio.imitate.segment_sam`; nothing is ever downloaded).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np

from studio.imitate.segment_track import DIS_PRESETS, Tracker, WorkFrames, first_from_box
from studio.imitate.targets import TargetError

log = logging.getLogger(__name__)

Progress = Callable[[str, int, int], None]  # progress(stage, step, total); stage "segment"


@dataclass(frozen=True)
class SegmentConfig:
    """How footage is segmented (defaults measured on four DAVIS sequences, the same for all of them)."""

    method: str = "auto"  # "auto" (Segment Anything when its package and sam_checkpoint exist, else classical),
    # "classical", or "sam" (an error that says what is missing when it cannot run)
    work_size: int = 400  # longest side (px) frames are segmented at (smaller ones as they are); masks upsampled back
    flow_preset: str = "medium"  # DIS optical-flow preset: "ultrafast", "fast" or "medium"
    first_gaps: tuple[int, ...] = (1, 2, 3)  # later frames whose flow from frame 0 gives the box's motion cue
    first_iterations: int = 4  # colour re-learning + graph-cut rounds for the first frame from a box
    first_motion_scale: float = 2.0  # first-frame motion evidence = scale · log(residual / Otsu level) …
    first_motion_clip: float = 3.0  # … clipped to ± this
    smoothness: float = 2.0  # graph-cut weight of the contrast-sensitive Potts term (per neighbour pair)
    colour_bins: int = 16  # global colour histograms: bins per RGB channel
    colour_weight: float = 1.0  # weight of the global colour evidence
    colour_clip: float = 5.0  # global and local colour evidence clipped to ± this (log-likelihood ratio)
    fg_anchor: float = 0.5  # object colour model: this share from the first frame, the rest from recent frames
    bg_anchor: float = 0.5  # background model: this share running (from past frames), the rest from this frame
    model_update: float = 0.3  # running colour models: weight of each new frame's colours
    bg_ring: float = 0.3  # background colours are sampled in a band this × size wide around the object
    local_weight: float = 1.0  # weight of the bilateral-grid (local) colour evidence
    local_cell: float = 0.15  # its spatial cell, × size (at least 4 px)
    local_bins: int = 8  # its colour bins per channel
    local_blur: tuple[float, float] = (1.0, 0.7)  # its Gaussian blur in cells: (space, colour)
    local_guard: float = 0.04  # its samples leave out a band this × size wide on each side of the guess's edge
    local_eps: float = 0.05  # added to both blurred counts before their ratio (how fast it trusts few samples)
    shape_weight: float = 1.0  # weight of the warped previous mask (shape prior)
    shape_sigma: float = 0.1  # shape prior = signed distance to the warped mask / (this × size) …
    shape_clip: float = 3.0  # … clipped to ± this
    far: float = 0.6  # pixels farther than this × size from the warped mask are definite background
    roi_margin: float = 0.4  # the graph cut covers the warped mask's box grown by this × size on each side
    motion_weight: float = 1.0  # weight of the motion evidence (times its measured reliability); 0 = no motion
    motion_noise: float = 0.3  # smallest flow residual σ (px at work size)
    motion_clip: float = 4.0  # motion evidence clipped to ± this
    motion_fp: tuple[float, float] = (0.25, 0.45)  # motion off as its false-object share outside rises over these
    min_component_share: float = 0.05  # pieces smaller than this share of the largest are dropped
    sam_checkpoint: str | None = None  # a local Segment Anything checkpoint (.pth for segment_anything, .pt sam2)
    sam_model: str = ""  # segment_anything model type ("vit_b", …) or sam2 config; "" = from the file name
    sam_device: str = "auto"  # torch device for Segment Anything ("auto" = cuda when available, else cpu)
    sam_box_grow: float = 0.1  # each frame's box prompt: the previous mask's box grown by this share per side

    def __post_init__(self) -> None:
        if self.method not in ("auto", "classical", "sam"):
            raise ValueError(f"method must be 'auto', 'classical' or 'sam', not {self.method!r}")
        if self.flow_preset not in DIS_PRESETS:
            raise ValueError(f"flow_preset must be one of {sorted(DIS_PRESETS)}, not {self.flow_preset!r}")
        if self.work_size < 32 or self.first_iterations < 1 or self.colour_bins < 2 or self.local_bins < 2:
            raise ValueError("work_size must be ≥ 32, first_iterations ≥ 1, colour_bins and local_bins ≥ 2")


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
    progress: Progress | None = None,
    cancel: threading.Event | None = None,
) -> np.ndarray:
    """The object's masks ``(N, H, W)`` uint8 {0, 1} in RGB ``frames`` ``(N, H, W, 3)`` uint8, given in frame 0 as a
    ``box`` (x, y, w, h) px or a ``first_mask`` ``(H, W)`` (nonzero = object), one of the two.

    ``progress("segment", step, total)`` after each frame; setting ``cancel`` stops within a frame and returns the
    masks of the frames done so far (fewer than N). Bad input raises :class:`TargetError` saying what to fix.
    """
    cfg = cfg or SegmentConfig()
    box, mask = check_inputs(frames, box, first_mask)
    frames = np.asarray(frames)
    if cfg.method != "classical":
        from studio.imitate.segment_sam import segment_video_sam, unavailable

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
        if progress is not None:
            progress("segment", t + 1, n)

    emit(0, cur)
    track = Tracker(work, cur, cfg)
    for t in range(1, n):
        if cancel is not None and cancel.is_set():
            log.info("segmentation cancelled after %d of %d frames", t, n)
            return out[:t]
        cur = track.step(t, cur)
        emit(t, cur)
    return out
