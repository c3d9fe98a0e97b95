"""Video targets: a video file or a folder of frames → binary shadow masks ``(N, S, S)`` in one square frame.

DESIGN §4 "Video targets". :func:`load_video` reads the source sampled at ``hz`` (:mod:`studio.targets.footage`:
video files through OpenCV, GIFs through Pillow with their real frame durations, frame folders at ``fps``), then

1. tells what the frames are (``kind="auto"``): colour footage (the channels differ by more than
   ``colour_spread`` on average), masks (every pixel 0 or 255, as DAVIS ground truth) or grey shadow footage;
2. binarises them with the still-target pieces of :mod:`studio.targets.images`, one polarity for the whole
   sequence (found on the borders of all sampled frames): masks as they are; shadow footage by ``threshold``
   (paper: grey 128) or Otsu, then a photographed backdrop's ruled lines and specks removed
   (:mod:`studio.targets.cleanup`), the largest pieces kept and crease holes filled (a hole is an opening when it
   is as light as a grey backdrop, ``backdrop_level``); a frame with no shadow is skipped and counted;
3. frames every mask in ONE square frame: the union of the shadow boxes of all frames, grown by ``margin`` and
   squared about its centre, resized to ``size × size``, so motion stays visible (the losses still crop each
   frame to its own box), keeping the gaps the resize would close (:mod:`studio.targets.holes`: each frame has
   its mask's holes and no others). The source frames are cropped the same way for review.

Raw colour footage needs segmentation (:mod:`studio.targets.segment`), so ``kind="auto"`` never thresholds it:
it raises :class:`SegmentationNeeded`, which carries the sampled RGB frames (:func:`studio.targets.source.raw_frames`
gives them directly), and :func:`video_from_masks` frames masks made by segmentation like any others;
:func:`studio.targets.source.open_source` does both.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from studio.assets import asset
from studio.errors import ProgressFn, TargetError, report
from studio.targets.cleanup import clean_shadow
from studio.targets.footage import Footage, read_footage
from studio.targets.images import (  # the framing helpers live with the stills' square_frame
    TargetConfig,
    check_shape_size,
    crop_square,
    detect_polarity,
    mask_from_grey,
    shadow_box,
    shadowness,
    square_box,
    square_mask,
    threshold_level,
)
from studio.targets.sampling import sample_times  # (public here: the video face)

__all__ = [
    "DEFAULT_VIDEO",
    "SegmentationNeeded",
    "Video",
    "VideoConfig",
    "detect_kind",
    "load_video",
    "read_footage",
    "sample_times",
    "video_from_masks",
]

log = logging.getLogger(__name__)

DEFAULT_VIDEO = asset("videos/muybridge_horse.gif")  # Muybridge's galloping horse (1878), SOURCE.txt beside it


@dataclass(frozen=True)
class VideoConfig:
    """How a video becomes a sequence of shadow masks (defaults: the paper's, and load every shared sequence)."""

    hz: float = 4.0  # sampling rate (paper 2.35–5.48 Hz); sample k: the source frame nearest k / hz (≤ fps) (0, 240]
    fps: float | None = None  # source rate of a frame folder (None: 24); a video file or GIF has its own (0, 1000]
    # size: a project stores every frame's masks at this side (N × S² bytes, twice): 2048 keeps a 1,000-frame
    # project within ~8 GB; the self-model works at 128-256
    size: int = 128  # side of the square frame all masks share, pixels [8, 2048]
    threshold: float | None = 128.0  # shadowness level for shadow footage (paper: grey 128); None = Otsu [0, 255)
    kind: str = "auto"  # "mask" | "shadow" | "auto" (colour → segmentation needed, binary {0,255} → mask, else shadow)
    margin: float = 0.1  # margin around the union of the shadow boxes on each side, fraction of its longer side
    polarity: str = "auto"  # "auto" (the borders of all sampled frames), "bright" (shape on black), "dark" (on white)
    auto_otsu: bool = True  # shadow footage: Otsu when the fixed threshold would make the backdrop shadow
    backdrop_level: float = 0.75  # shadow footage: a hole whose pixels are at most this × threshold is an opening
    line_length: float = 0.3  # shadow footage: remove ruled lines this long (× longer side) …; 0 = keep them
    line_thickness: float = 0.05  # … and at most this thick (× shorter side) (a photographed backdrop's rules)
    speck_radius: float = 0.01  # shadow footage: remove bits thinner than a disc this wide (× shorter side)
    colour_spread: float = 12.0  # "auto": mean channel spread (max − min, grey levels) above which it is colour
    max_bad_share: float = 0.25  # more than this share of the sampled frames unreadable is an error [0, 1]
    keep_frames: bool = True  # keep the framed source frames (Video.frames) for review

    def __post_init__(self) -> None:
        if not self.hz > 0 or (self.fps is not None and not self.fps > 0):
            raise ValueError("hz and fps must be positive frame rates")
        if self.kind not in ("auto", "mask", "shadow"):
            raise ValueError(f"kind must be 'auto', 'mask' or 'shadow', not {self.kind!r}")
        if self.polarity not in ("auto", "bright", "dark"):
            raise ValueError(f"polarity must be 'auto', 'bright' or 'dark', not {self.polarity!r}")
        if not 8 <= self.size <= 2048 or self.margin < 0 or not 0 <= self.max_bad_share <= 1:
            raise ValueError("size must be in [8, 2048] pixels, margin ≥ 0 and max_bad_share in [0, 1]")
        if self.threshold is not None and not 0 <= self.threshold < 255:
            raise ValueError("threshold must be a grey level in [0, 255) or None (Otsu)")


@dataclass
class Video:
    """A sampled video target: masks ``(N, S, S)`` framed in one square frame, each with its source time."""

    source: Path  # the file or folder read
    fps: float  # source frame rate (a GIF: its mean rate)
    hz: float  # sampling rate
    times: np.ndarray  # (N,) s, source time of each sampled frame
    frame_index: np.ndarray  # (N,) int, index of the source frame
    masks: np.ndarray  # (N, S, S) uint8, 1 = shadow, all framed in ONE square frame (box)
    frames: np.ndarray | None  # (N, S, S, 3) uint8 RGB source frames framed the same way (review); None if not kept
    skipped: list[tuple[int, str]]  # (source index, reason) of the sampled frames left out, logged
    box: tuple[int, int, int, int]  # the shared square frame in source pixels (x, y, w, h); may reach outside
    kind: str = "shadow"  # what the frames were: "mask", "shadow" or "segmented"
    polarity: str = "bright"  # the sequence's polarity ("bright": bright shape on a dark ground)
    duration_s: float = 0.0  # the source's clock, s
    n_source: int = 0  # frames in the source
    cancelled: bool = False  # the cancel event stopped the reading: only the frames read before it
    shadow_share: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (N,) shadow fraction of each mask


class SegmentationNeeded(TargetError):
    """The footage is in colour: a shadow must be segmented from it first (its sampled frames are ``footage``)."""

    def __init__(self, message: str, footage: Footage):
        super().__init__(message)
        self.footage = footage  # the sampled RGB frames and times, for studio.targets.segment


def _grey(frames: np.ndarray) -> np.ndarray:
    """RGB ``(N, H, W, 3)`` → luminance ``(N, H, W)`` uint8."""
    return np.stack([cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]) if len(frames) else frames[..., 0]


def detect_kind(frames: np.ndarray, colour_spread: float = VideoConfig.colour_spread) -> str:
    """What sampled RGB frames ``(N, H, W, 3)`` are: ``"colour"`` footage, binary ``"mask"`` frames or grey
    ``"shadow"`` footage (module doc, step 1)."""
    step = max(1, len(frames) // 16)  # a spread of frames is enough to tell
    sub = frames[::step].astype(np.int16)
    if float((sub.max(axis=-1) - sub.min(axis=-1)).mean()) > colour_spread:
        return "colour"
    return "mask" if np.isin(frames[::step], (0, 255)).all() else "shadow"


def shadow_mask(grey: np.ndarray, polarity: str, cfg: VideoConfig, source: str = "<frame>") -> np.ndarray:
    """One grey frame ``(H, W)`` of shadow footage → its mask ``(H, W)`` uint8 (module doc, step 2): threshold,
    ruled lines and specks removed (:mod:`studio.targets.cleanup`), then the still-target pieces and holes."""
    target_cfg = TargetConfig(  # no crease pockets: a shadow has no skin, its mid-dark is penumbra (a real gap's)
        polarity=polarity, threshold=cfg.threshold, auto_otsu=cfg.auto_otsu, backdrop_level=cfg.backdrop_level,
        pocket_reach=0.0,
    )  # fmt: skip
    shade = shadowness(grey, polarity)
    level = threshold_level(shade, target_cfg, source)
    raw = (shade > level).astype(np.uint8)
    removed = raw & (1 - clean_shadow(raw, cfg.line_length, cfg.line_thickness, cfg.speck_radius))
    shade = np.where(removed > 0, 0, shade).astype(np.uint8)  # what was removed is surely backdrop now
    cleaned_cfg = replace(target_cfg, polarity="bright", threshold=min(level, 254.0), auto_otsu=False)
    return mask_from_grey(shade, cleaned_cfg, source)


def frame_mask(grey: np.ndarray, kind: str, polarity: str, cfg: VideoConfig, source: str = "<frame>") -> np.ndarray:
    """One sampled grey frame ``(H, W)`` → the mask ``(H, W)`` uint8 that :func:`load_video` keeps for it (step 2,
    the sequence's ``polarity`` found beforehand): a ``"mask"`` frame as it is, shadow footage by
    :func:`shadow_mask` (a TargetError when no shadow is left). What the studio's Targets panel previews as stored."""
    if kind == "mask":
        return (shadowness(grey, polarity) > 127).astype(np.uint8)
    return shadow_mask(grey, polarity, cfg, source)


def video_from_masks(
    footage: Footage,
    masks: np.ndarray,
    cfg: VideoConfig | None = None,
    skipped: list[tuple[int, str]] | None = None,
    kind: str = "segmented",
    polarity: str = "bright",
    progress: ProgressFn | None = None,
) -> Video:
    """Frame source-size masks ``(N, H, W)`` (1 = shadow, one per sampled frame of ``footage``) in one square frame.

    Empty masks are skipped (with the frames ``skipped`` before) and counted; ``Progress("frame", step, total)`` events.
    """
    cfg = cfg or VideoConfig()
    skipped = list(footage.skipped) + list(skipped or [])
    keep = [k for k in range(len(masks)) if masks[k].any()]
    already = {i for i, _ in skipped}
    for k in range(len(masks)):
        if not masks[k].any() and int(footage.frame_index[k]) not in already:
            skipped.append((int(footage.frame_index[k]), "no shadow pixels"))
    if not keep:
        raise TargetError(f"no sampled frame has any shadow (check the threshold, polarity or kind): {footage.source}")
    boxes = [shadow_box(masks[k]) for k in keep]
    check_shape_size(boxes, str(footage.source))
    box = square_box(boxes, cfg.margin)
    out_masks, out_frames, kept = [], [], []
    for step, k in enumerate(keep):
        m = square_mask(masks[k], box, cfg.size)
        if not m.any():
            skipped.append((int(footage.frame_index[k]), f"the shadow vanishes at {cfg.size}×{cfg.size} pixels"))
        else:
            out_masks.append(m)
            kept.append(k)
            if cfg.keep_frames:
                out_frames.append(np.clip(crop_square(footage.frames[k], box, cfg.size) + 0.5, 0, 255).astype(np.uint8))
        report(progress, "frame", step + 1, len(keep))
    if not out_masks:
        raise TargetError(f"every shadow vanishes at {cfg.size}×{cfg.size} pixels (a larger size?): {footage.source}")
    skipped.sort()
    late = [s for s in skipped if s not in footage.skipped]
    if late:
        log.warning("%s: %d sampled frames left out: %s", footage.source, len(late), late[:3])
    stack = np.stack(out_masks)
    return Video(
        source=footage.source,
        fps=footage.fps,
        hz=footage.hz,
        times=footage.times[kept],
        frame_index=footage.frame_index[kept],
        masks=stack,
        frames=np.stack(out_frames) if cfg.keep_frames else None,
        skipped=skipped,
        box=tuple(int(v) for v in box),
        kind=kind,
        polarity=polarity,
        duration_s=footage.duration_s,
        n_source=footage.n_source,
        cancelled=footage.cancelled,
        shadow_share=stack.reshape(len(stack), -1).mean(axis=1),
    )


def load_video(
    path: str | Path,
    cfg: VideoConfig | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> Video:
    """Load a video target: masks ``(N, S, S)`` uint8 in one square frame, with source times (module doc).

    Progress events for the stages "read", "binarise" and "frame"; setting ``cancel`` stops the reading (the slow
    part) early: the frames read so far are binarised and the result is flagged ``cancelled``. Raises
    :class:`~studio.errors.TargetError` naming the file for bad input, and :class:`SegmentationNeeded` for colour
    footage with ``kind="auto"``.
    """
    cfg = cfg or VideoConfig()
    footage = read_footage(path, cfg.hz, cfg.fps, cfg.max_bad_share, progress, cancel)
    if footage.cancelled and len(footage.frames) == 0:  # cancelled before the first frame: nothing to frame
        empty = np.zeros((0, cfg.size, cfg.size), np.uint8)
        frames = np.zeros((0, cfg.size, cfg.size, 3), np.uint8) if cfg.keep_frames else None
        return Video(
            footage.source,
            footage.fps,
            footage.hz,
            footage.times,
            footage.frame_index,
            empty,
            frames,
            footage.skipped,
            (0, 0, 0, 0),
            duration_s=footage.duration_s,
            n_source=footage.n_source,
            cancelled=True,
        )
    grey = _grey(footage.frames)
    kind = cfg.kind
    if kind == "auto":
        kind = detect_kind(footage.frames, cfg.colour_spread)
        if kind == "colour":
            raise SegmentationNeeded(
                f"{footage.source.name} is colour footage, not shadow footage or masks, and a threshold would turn it "
                "into noise: give the object's box or mask in its first frame so that it is segmented: "
                f"{footage.source}",
                footage,
            )
    polarity = detect_polarity(grey) if cfg.polarity == "auto" else cfg.polarity
    masks, skipped = np.zeros(grey.shape, np.uint8), []
    for k in range(len(grey)):
        try:
            masks[k] = frame_mask(grey[k], kind, polarity, cfg, source=f"frame {footage.frame_index[k]}")
        except TargetError as e:
            skipped.append((int(footage.frame_index[k]), str(e)))
        report(progress, "binarise", k + 1, len(grey))
    video = video_from_masks(footage, masks, cfg, skipped, kind, polarity, progress)
    log.info(
        "video %s: %d of %d sampled frames (%s, %s polarity) at %g Hz, frame %s",
        footage.source,
        len(video.masks),
        len(video.masks) + len(video.skipped),
        kind,
        polarity,
        cfg.hz,
        video.box,
    )
    return video
