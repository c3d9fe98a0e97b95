"""Live targets: one camera frame → the target mask ``(R, R)`` uint8 the search uses, in a few milliseconds.

A live mode films the artist's hand shadow on a wall (dark on light, uneven light), a silhouette held up, a mask
video (white on black) or any footage at ~30 fps; :class:`LiveTargets` turns each BGR frame into a mask framed
like a still target (:func:`~studio.targets.images.square_frame` about the shadow's box with the
:class:`~studio.targets.images.TargetConfig` margin, as ``load_target`` frames ``frame="shadow"``), or into
``None`` and one sentence for the artist when the frame holds no usable silhouette. Every frame is first reduced
to grey at ``work_size`` (the speed), then:

* **with a backdrop homography** (the rig's calibration): the shadow window is rectified out of it
  (:func:`~studio.targets.backdrop.rectify`) and binarised against its own light
  (:func:`~studio.targets.backdrop.binarise`, robust to uneven light); the largest pieces are kept;
* **without one**: the polarity is decided once, on the first frame with a silhouette whose border is clearly
  dark or clearly light (:func:`~studio.targets.images.detect_polarity`), and kept; the shadowness is split by
  Otsu, the backdrop's level is fitted by a smooth quadratic surface over the backdrop's pixels and divided out
  (a wall lit from one side is no shadow; what is left is each pixel's contrast against the wall behind it),
  split by Otsu again, specks removed (:func:`~studio.targets.cleanup.remove_specks`), the largest pieces kept
  and crease holes filled (:func:`~studio.targets.holes.fill_holes`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from studio.errors import TargetError
from studio.targets.backdrop import binarise, rectify
from studio.targets.cleanup import remove_specks
from studio.targets.holes import fill_holes
from studio.targets.images import (
    TargetConfig,
    detect_polarity,
    keep_largest_components,
    shadow_box,
    shadowness,
    square_frame,
    threshold_level,
)

__all__ = ["LiveTarget", "LiveTargetConfig", "LiveTargets"]

_OTSU = TargetConfig(threshold=None)  # threshold_level → Otsu's level; its piece and hole rules for live frames
_AMBIGUOUS_GREY = 32  # a border median within this many grey levels of 128 does not decide the polarity
_FIT_STEP = 4  # the backdrop's surface is fitted to every 4th pixel of each axis


@dataclass(frozen=True)
class LiveTargetConfig:
    """How a live camera frame becomes a target mask (defaults: a hand shadow on a wall, DAVIS masks)."""

    resolution: int = 128  # side of the target mask, pixels [8, 2048]
    polarity: str = "auto"  # "auto" (first clear frame borders, then kept), "dark" (shadow on a wall), "bright"
    work_size: int = 320  # longer side the frame is reduced to before thresholding (speed), pixels [32, 4096]
    min_share: float = 0.002  # silhouette smaller than this share of the frame: none (below max_share) [0, 1)
    max_share: float = 0.6  # larger: none (the backdrop reads as shadow) (0, 1]
    max_components: int = 2  # largest 8-connected pieces kept [1, 1000]
    margin: float = TargetConfig.margin  # frame margin around the shadow box, share of its longer side [0, 10]
    min_contrast: float = 0.25  # a shadow is at least this much darker than the wall behind it, share of it [0, 1)
    speck_radius: int = 1  # shadow bits thinner than a disc of this radius go, work-size pixels [0, 16]
    window_size: int = 160  # backdrop path: side of the rectified window binarised, pixels [32, 1024] (~R² cost)

    def __post_init__(self) -> None:
        if self.polarity not in ("auto", "dark", "bright"):
            raise ValueError(f"polarity must be 'auto', 'dark' or 'bright', not {self.polarity!r}")
        if not 8 <= self.resolution <= 2048 or not 32 <= self.work_size <= 4096:
            raise ValueError("resolution must be in [8, 2048] and work_size in [32, 4096] pixels")
        if not 0 <= self.min_share < self.max_share <= 1:
            raise ValueError("min_share and max_share must satisfy 0 ≤ min_share < max_share ≤ 1")
        if not 1 <= self.max_components <= 1000 or not 0 <= self.margin <= 10:
            raise ValueError("max_components must be in [1, 1000] and margin in [0, 10]")
        if not 0 <= self.min_contrast < 1 or not 0 <= self.speck_radius <= 16 or not 32 <= self.window_size <= 1024:
            raise ValueError("min_contrast must be in [0, 1), speck_radius in [0, 16], window_size in [32, 1024]")


@dataclass(frozen=True)
class LiveTarget:
    """One frame's target: the framed mask, or None and why."""

    mask: np.ndarray | None  # (R, R) uint8, 1 = shadow; None: no silhouette in the frame
    reason: str  # "" when mask is given, else one sentence for the artist ("no silhouette: ...")
    share: float  # shadow share of the (work-size) frame, or of the shadow window with a homography [0, 1]
    seconds: float  # time spent on the frame, s


def _grey(image: np.ndarray) -> np.ndarray:
    """A frame ``(H, W, 3)`` BGR or ``(H, W)`` grey uint8 → grey ``(H, W)`` uint8; ValueError for anything else."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8:
        raise ValueError(
            f"a live frame must be a uint8 numpy array, got {type(image).__name__} {getattr(image, 'dtype', '')}"
        )
    if not (image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)) or min(image.shape[:2]) < 2:
        raise ValueError(f"a live frame must be (H, W, 3) BGR or (H, W) grey, at least 2×2, got shape {image.shape}")
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def _clear_polarity(grey: np.ndarray) -> str | None:
    """detect_polarity's answer when the border is clearly dark or light (the same with every grey level shifted
    by ±_AMBIGUOUS_GREY), else None."""
    lighter = detect_polarity(cv2.add(grey, _AMBIGUOUS_GREY))
    return lighter if lighter == detect_polarity(cv2.subtract(grey, _AMBIGUOUS_GREY)) else None


@lru_cache(maxsize=4)
def _surface_terms(h: int, w: int) -> np.ndarray:
    """The quadratic surface's terms ``(h, w, 6)`` float32 over ``[-1, 1]²``: 1, x, y, x², xy, y²."""
    y, x = np.mgrid[-1 : 1 : h * 1j, -1 : 1 : w * 1j].astype(np.float32)
    return np.stack([np.ones_like(x), x, y, x * x, x * y, y * y], axis=-1)


def _backdrop_level(shade: np.ndarray, backdrop: np.ndarray) -> np.ndarray:
    """A smooth map ``(H, W)`` float32 of the backdrop's shadowness: a quadratic surface least-squares fitted to
    the ``backdrop`` pixels (every ``_FIT_STEP``-th); their median when they are too few to fit it."""
    terms = _surface_terms(*shade.shape)
    pick = backdrop[::_FIT_STEP, ::_FIT_STEP]
    if pick.mean() < 0.25:  # a small backdrop (a corner, a strip) would let the surface run wild elsewhere
        return np.full(shade.shape, np.median(shade[backdrop]), np.float32)
    coef, *_ = np.linalg.lstsq(terms[::_FIT_STEP, ::_FIT_STEP][pick], shade[::_FIT_STEP, ::_FIT_STEP][pick], rcond=None)
    return terms @ coef.astype(np.float32)


class LiveTargets:
    """Frame after frame → :class:`LiveTarget` (module doc). ``H_backdrop_camera`` ``(3, 3)``: camera pixels →
    backdrop metres (rig calibration), with the shadow window ``window_m`` wide; None: the whole frame is the wall."""

    def __init__(
        self, cfg: LiveTargetConfig | None = None, H_backdrop_camera: np.ndarray | None = None, window_m: float = 0.6
    ):
        self.cfg = cfg or LiveTargetConfig()
        self.H_backdrop_camera = None if H_backdrop_camera is None else np.asarray(H_backdrop_camera, np.float64)
        if self.H_backdrop_camera is not None and self.H_backdrop_camera.shape != (3, 3):
            raise ValueError(f"H_backdrop_camera must be a (3, 3) homography, got shape {self.H_backdrop_camera.shape}")
        if not window_m > 0:
            raise ValueError("window_m must be a positive width in metres")
        self.window_m = window_m
        auto = self.cfg.polarity == "auto"
        self.polarity = "dark" if auto and self.H_backdrop_camera is not None else self.cfg.polarity

    def __call__(self, image_bgr: np.ndarray) -> LiveTarget:
        t0 = time.perf_counter()
        grey = _grey(image_bgr)
        scale = min(1.0, self.cfg.work_size / max(grey.shape))
        if scale < 1:
            size = (max(2, round(grey.shape[1] * scale)), max(2, round(grey.shape[0] * scale)))
            grey_small = cv2.resize(grey, size, interpolation=cv2.INTER_AREA)
        else:
            grey_small = grey
        if self.H_backdrop_camera is not None:
            mask, reason = self._window_mask(grey_small, grey.shape)
        else:
            mask, reason = self._wall_mask(grey_small)
        share = float(mask.mean()) if mask is not None else 0.0
        if not reason and (share < self.cfg.min_share or not mask.any()):
            reason = f"the shadow is too small: {share:.1%} of the frame (at least {self.cfg.min_share:.1%})"
        if not reason and share > self.cfg.max_share:
            reason = (
                f"the shadow covers {share:.0%} of the frame (at most {self.cfg.max_share:.0%}): the backdrop reads "
                "as shadow; light it more or step back"
            )
        if not reason and self.polarity == "auto" and (clear := _clear_polarity(grey_small)) is not None:
            self.polarity = clear  # decided on a frame with a usable silhouette and a clear border: kept from now on
        framed = None
        if not reason:
            framed = square_frame(mask, self.cfg.resolution, shadow_box(mask), self.cfg.margin)
            if not framed.any():
                reason, framed = f"the shadow vanishes at {self.cfg.resolution}×{self.cfg.resolution} pixels", None
        return LiveTarget(framed, f"no silhouette: {reason}" if reason else "", share, time.perf_counter() - t0)

    def _window_mask(self, grey_small: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray | None, str]:
        """The backdrop path: rectified and binarised shadow window ``(S, S)`` and the reason when it has none."""
        sy, sx = grey_small.shape[0] / shape[0], grey_small.shape[1] / shape[1]
        # camera pixels → reduced pixels (OpenCV's centres: x' = (x + 0.5) s − 0.5), so H maps reduced → backdrop
        S = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])
        window = rectify(grey_small, self.H_backdrop_camera @ np.linalg.inv(S), self.window_m, self.cfg.window_size)
        if self.polarity == "bright":
            window = 1.0 - window
        mask = binarise(window, self.cfg.min_contrast)
        if not mask.any():
            return None, "no shadow in the shadow window (nothing clearly darker than the lit backdrop)"
        return keep_largest_components(mask, self.cfg.max_components, _OTSU.min_component_share), ""

    def _wall_mask(self, grey: np.ndarray) -> tuple[np.ndarray | None, str]:
        """The whole-frame path on grey ``(h, w)`` uint8: the mask ``(h, w)`` and the reason when there is none."""
        polarity = self.polarity if self.polarity != "auto" else detect_polarity(grey)
        dark = polarity == "dark"
        shade = shadowness(grey, polarity)
        try:
            level = threshold_level(shade, _OTSU)
        except TargetError:
            return None, f"the frame is one flat grey level ({int(grey[0, 0])}): a blank wall or a covered camera"
        backdrop = _backdrop_level(shade.astype(np.float32), shade <= level)
        room = 255.0 - backdrop  # how much darker than the backdrop a pixel can be
        if float(room.mean()) < 255 * self.cfg.min_contrast:
            what = "wall is too dark to show a shadow (is the light on?)" if dark else "backdrop is not dark enough"
            return None, f"the {what}"
        contrast = np.clip((shade - backdrop) / np.maximum(room, 1.0), 0.0, 1.0)
        contrast = (contrast * 255 + 0.5).astype(np.uint8)  # each pixel's darkness against the wall behind it
        try:
            level = threshold_level(contrast, _OTSU)
        except TargetError:
            level = 255.0
        mask = (contrast > level).astype(np.uint8)
        found = (float(contrast[mask > 0].mean()) - float(contrast[mask == 0].mean())) / 255 if mask.any() else 0.0
        if found < self.cfg.min_contrast:
            what = "darker than the wall" if dark else "brighter than the backdrop"
            return None, f"nothing is clearly {what} (contrast {found:.2f}, at least {self.cfg.min_contrast:.2f})"
        mask = remove_specks(mask, self.cfg.speck_radius)
        mask = keep_largest_components(mask, self.cfg.max_components, _OTSU.min_component_share)
        mask = fill_holes(mask, contrast, _OTSU.backdrop_level * level, _OTSU.min_hole_area, _OTSU.min_core_share)
        return mask, ""
