"""Still targets: an image file → a binary shadow mask ``(H, W)`` uint8, 1 = shadow (DESIGN §1).

The steps, each a config field with a default that loads every target in ``shared/targets`` cleanly:

1. Read the file (PNG, JPEG, GIF (first frame), BMP, TIFF, …; grey, 16-bit, colour or with an alpha channel) as
   a grey image. A non-constant alpha channel is the shape (opaque = shadow); otherwise the luminance is
   (16-bit and float images are stretched from their minimum to their maximum).
2. Polarity: the border pixels are mostly backdrop, so a dark border (median < 128) means a bright shape on black
   (ASL cut-outs, MPEG-7, DAVIS masks) and a bright border a dark shape on white. The image is turned into
   *shadowness* (0-255, high = shadow) accordingly.
3. Threshold the shadowness: a fixed level (default 25, right for the ASL cut-outs: dark skin stays shadow) or
   Otsu (``threshold=None``, for photographs whose backdrop is not black). With ``auto_otsu`` (the default) Otsu
   is also chosen by itself when the backdrop is not dark: when the median shadowness of the border is above the
   fixed level, that level would make the backdrop shadow (a grey wall, as in Muybridge's horse), so the image is
   split where its histogram says instead. Every ASL, MPEG-7 and DAVIS target has a black backdrop and keeps 25.
4. Keep the largest 8-connected pieces (``max_components``, ``min_component_share`` of the largest).
5. Fill holes (4-connected backdrop regions not touching the border) unless they are real openings. A hole is a
   real opening when its *core* (its surely-backdrop pixels, shadowness ≤ ``backdrop_level`` × threshold) covers at
   least ``min_hole_area`` and at least ``min_core_share`` of the hole. Dark creases between the fingers of a fist
   are mid-dark skin (shadowness 5-25) with little true black, so they fill; the opening of an ASL "o" shows the
   black backdrop and stays. In binary images every hole pixel is core, so only the area counts. Before that, the
   crease *pockets* are filled: mid-dark backdrop that surely-backdrop pixels do not reach (``pocket_reach`` of the
   shape's longer side) and that opens to the rest through a neck (``pocket_neck``), as a crease's shade does
   under a side light (:func:`~studio.targets.pockets.fill_pockets`). Binary images have no mid-dark pixels.

:func:`square_frame` turns a mask into the square ``size × size`` frame the optimiser works in, with the mask's
holes and no others (a gap narrower than a frame pixel stays open, :mod:`studio.targets.holes`, which also finds
the holes: the hole part of the expressive region, DESIGN §4). Target sets on disk (a folder's images, a numbered
image's class) are :mod:`studio.targets.image_sets`. Footage of shadows fills no pockets (:mod:`studio.targets.video`).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from studio.assets import asset
from studio.errors import TargetError
from studio.targets.holes import MIN_CORE_SHARE, MIN_HOLE_AREA, fill_holes, find_holes, threshold_keeping_gaps
from studio.targets.pockets import POCKET_NECK, POCKET_REACH, fill_pockets

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".gif", ".bmp", ".tif", ".tiff", ".webp")
SAMPLE_DIR = asset("targets")  # bundled sample targets (ASL letters, MPEG-7 silhouettes), SOURCE.txt beside them
DEFAULT_TARGET = SAMPLE_DIR / "asl_o.jpeg"  # the default example: ASL "o", whose opening is an expressive hole
MIN_SHAPE_SIDE = 8  # a shape whose longer side spans fewer source pixels has no outline to imitate (a speck)


@dataclass(frozen=True)
class TargetConfig:
    """How an image becomes a binary shadow mask (defaults load the ASL, MPEG-7 and DAVIS targets)."""

    polarity: str = "auto"  # "auto" (border = backdrop), "bright" (white shape on black), "dark" (black on white)
    threshold: float | None = 25.0  # shadowness (after polarity) above which a pixel is shadow; None: Otsu [0, 255)
    auto_otsu: bool = True  # use Otsu instead of the fixed threshold when the border (backdrop) is above it
    max_components: int = 3  # keep at most this many 8-connected shadow pieces, largest first [1, 1000]
    min_component_share: float = 0.1  # drop pieces smaller than this fraction of the largest piece (specks) [0, 1]
    min_hole_area: float = MIN_HOLE_AREA  # smallest real opening's core: < 1 → share of the shadow area, ≥ 1 → pixels
    min_core_share: float = MIN_CORE_SHARE  # a hole whose core is less than this share of its area is a crease [0, 1]
    backdrop_level: float = 0.25  # core pixels: shadowness ≤ backdrop_level × threshold (surely backdrop) [0, 1]
    pocket_reach: float = POCKET_REACH  # crease pockets: black backdrop's reach, × shape's longer side; 0: off [0, 1]
    pocket_neck: float = POCKET_NECK  # a pocket fills when under this share of its rim meets reached backdrop [0, 1]
    frame: str = "shadow"  # load_target(size=…) frames "shadow" (its bounding box + margin) or the whole "image"
    margin: float = 0.1  # frame margin around the shadow box on each side, fraction of its longer side [0, 10]

    def __post_init__(self) -> None:
        if self.polarity not in ("auto", "bright", "dark"):
            raise ValueError(f"polarity must be 'auto', 'bright' or 'dark', not {self.polarity!r}")
        if self.frame not in ("shadow", "image"):
            raise ValueError(f"frame must be 'shadow' or 'image', not {self.frame!r}")
        if self.threshold is not None and not 0 <= self.threshold < 255:
            raise ValueError("threshold must be a grey level in [0, 255) or None (Otsu)")
        if self.max_components < 1 or self.min_hole_area < 0 or self.margin < 0:
            raise ValueError("max_components must be ≥ 1, min_hole_area and margin ≥ 0")
        if not (0 <= self.pocket_reach <= 1 and 0 <= self.pocket_neck <= 1):
            raise ValueError("pocket_reach and pocket_neck must be shares in [0, 1]")


def read_grey(path: str | Path) -> np.ndarray:
    """The image at ``path`` as grey levels ``(H, W)`` uint8 (alpha, when it varies, is the shape)."""
    path = Path(path)
    if not path.exists():
        raise TargetError(f"target file not found: {path}")
    if not path.is_file():
        raise TargetError(f"target is not a file: {path}")
    try:
        with Image.open(path) as im:
            im.seek(0)
            im = ImageOps.exif_transpose(im)
            if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
                alpha = np.asarray(im.convert("RGBA"))[..., 3]
                if alpha.min() < alpha.max():
                    return np.ascontiguousarray(alpha)
            if im.mode in ("I", "F") or im.mode.startswith("I;16"):  # 16-bit/float: stretch to 0-255
                a = np.asarray(im, dtype=np.float64)
                span = a.max() - a.min()
                return np.zeros(a.shape, np.uint8) if span == 0 else ((a - a.min()) * (255 / span)).astype(np.uint8)
            return np.asarray(im.convert("L")).copy()
    except UnidentifiedImageError:
        raise TargetError(f"not an image (unknown format): {path}") from None
    except (OSError, ValueError, SyntaxError) as e:
        raise TargetError(f"unreadable image ({e}): {path}") from None


def detect_polarity(grey: np.ndarray) -> str:
    """The polarity rule (module doc, step 2) on grey ``(H, W)`` or a stack ``(N, H, W)`` (one answer for all):
    ``"bright"`` (a bright shape on a dark border) or ``"dark"`` (a dark shape on a bright border)."""
    border = np.concatenate([grey[..., 0, :], grey[..., -1, :], grey[..., :, 0], grey[..., :, -1]], axis=-1)
    return "bright" if np.median(border) < 128 else "dark"


def shadowness(grey: np.ndarray, polarity: str = "auto") -> np.ndarray:
    """Grey ``(H, W)`` uint8 → shadowness ``(H, W)`` uint8, high = shadow, by the polarity rule (module doc)."""
    if polarity == "auto":
        polarity = detect_polarity(grey)
    return grey if polarity == "bright" else 255 - grey


def backdrop_is_shadow(shade: np.ndarray, threshold: float) -> bool:
    """Whether the fixed ``threshold`` would make the backdrop shadow: the border's median shadowness is above it
    (and the image is not one flat level, where Otsu has nothing to split)."""
    border = np.concatenate([shade[0], shade[-1], shade[:, 0], shade[:, -1]])
    return bool(np.median(border) > threshold and shade.min() < shade.max())


def keep_largest_components(mask: np.ndarray, max_components: int = 1, min_share: float = 0.0) -> np.ndarray:
    """The ``max_components`` largest 8-connected pieces of ``mask`` at least ``min_share`` × the largest."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros_like(mask, dtype=np.uint8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    order = np.argsort(areas)[::-1][:max_components]
    keep = [1 + i for i in order if areas[i] >= min_share * areas[order[0]]]
    return np.isin(labels, keep).astype(np.uint8)


def threshold_level(shade: np.ndarray, cfg: TargetConfig, source: str = "<array>") -> float:
    """The shadowness level of step 3 for ``shade`` ``(H, W)`` uint8: ``cfg.threshold``, or Otsu's when it is None
    or (``auto_otsu``) when the fixed level would make the backdrop shadow; pixels above it are shadow."""
    if shade.min() == shade.max():  # black, white or one grey: no shape, whatever the level or the polarity
        raise TargetError(f"empty target: the image is one flat grey level, no shape to imitate: {source}")
    if cfg.threshold is None or (cfg.auto_otsu and backdrop_is_shadow(shade, cfg.threshold)):
        level, _ = cv2.threshold(shade, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        return float(level)
    return float(cfg.threshold)


def mask_from_grey(grey: np.ndarray, cfg: TargetConfig | None = None, source: str = "<array>") -> np.ndarray:
    """Grey image ``(H, W)`` uint8 → shadow mask ``(H, W)`` uint8 (steps 2-5); errors name ``source``."""
    cfg = cfg or TargetConfig()
    if grey.ndim != 2 or min(grey.shape) < 2:
        raise TargetError(f"image must be at least 2×2 pixels, got shape {grey.shape}: {source}")
    shade = shadowness(grey, cfg.polarity)
    level = threshold_level(shade, cfg, source)
    mask = (shade > level).astype(np.uint8)
    if not mask.any():
        raise TargetError(f"empty target: no shadow pixels (none above grey level {level:.0f}): {source}")
    if mask.all():
        raise TargetError(f"every pixel is shadow (no backdrop, check the polarity/threshold): {source}")
    mask = keep_largest_components(mask, cfg.max_components, cfg.min_component_share)
    core_level = cfg.backdrop_level * level
    mask = fill_pockets(
        mask, shade, core_level, cfg.pocket_reach, cfg.pocket_neck, cfg.min_hole_area, cfg.min_core_share
    )
    mask = fill_holes(mask, shade, core_level, cfg.min_hole_area, cfg.min_core_share)
    if mask.all():
        raise TargetError(f"every pixel is shadow after filling holes (no backdrop left): {source}")
    return mask


def shadow_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    """Bounding box of the shadow pixels as pixel edges ``(row0, row1, col0, col1)`` (row1/col1 exclusive)."""
    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        raise TargetError("empty mask: no shadow pixels to frame")
    return int(rows.min()), int(rows.max()) + 1, int(cols.min()), int(cols.max()) + 1


def check_shape_size(boxes: list[tuple[int, int, int, int]], source: str) -> None:
    """A :class:`TargetError` when the union of shadow boxes ``(row0, row1, col0, col1)`` spans fewer than
    :data:`MIN_SHAPE_SIDE` source pixels on its longer side: framing would blow a speck up into a block."""
    rows = max(b[1] for b in boxes) - min(b[0] for b in boxes)
    cols = max(b[3] for b in boxes) - min(b[2] for b in boxes)
    if max(rows, cols) < MIN_SHAPE_SIDE:
        raise TargetError(
            f"the shape is only {cols}×{rows} pixels in the image, too small to have an outline (at least "
            f"{MIN_SHAPE_SIDE} pixels across): {source}"
        )


def square_box(boxes: list[tuple[int, int, int, int]], margin: float) -> tuple[int, int, int, int]:
    """The square frame ``(x, y, w, h)`` around the union of shadow boxes ``(row0, row1, col0, col1)``: grown by
    ``margin`` × its longer side on each side and squared about its centre (as :func:`square_frame` frames a still)."""
    r0, r1 = min(b[0] for b in boxes), max(b[1] for b in boxes)
    c0, c1 = min(b[2] for b in boxes), max(b[3] for b in boxes)
    longer = max(r1 - r0, c1 - c0)
    side = max(1, longer + 2 * int(round(margin * longer)))
    return (c0 + c1 - side) // 2, (r0 + r1 - side) // 2, side, side


def crop_square(image: np.ndarray, box: tuple[int, int, int, int], size: int) -> np.ndarray:
    """``image`` ``(H, W)`` or ``(H, W, C)`` inside ``box`` ``(x, y, w, h)`` (outside the image: zeros), resized
    to ``(size, size[, C])`` by area averaging; float32."""
    x, y, w, h = box
    canvas = np.zeros((h, w) + image.shape[2:], np.float32)
    sr0, sr1, sc0, sc1 = max(y, 0), min(y + h, image.shape[0]), max(x, 0), min(x + w, image.shape[1])
    if sr1 > sr0 and sc1 > sc0:
        canvas[sr0 - y : sr1 - y, sc0 - x : sc1 - x] = image[sr0:sr1, sc0:sc1]
    return cv2.resize(canvas, (size, size), interpolation=cv2.INTER_AREA)


def square_mask(mask: np.ndarray, box: tuple[int, int, int, int], size: int) -> np.ndarray:
    """Mask ``(H, W)`` inside ``box`` ``(x, y, w, h)`` at ``(size, size)`` uint8, as a video frame is stored: area
    averaged and thresholded at half coverage, with the mask's holes and no others (a gap narrower than a frame pixel
    stays open, :func:`~studio.targets.holes.threshold_keeping_gaps`)."""
    cover = crop_square(np.asarray(mask, np.float32), box, size)
    return threshold_keeping_gaps(cover, crop_square(find_holes(mask).astype(np.float32), box, size))


def square_frame(
    mask: np.ndarray, size: int, box: tuple[int, int, int, int] | None = None, margin: float = 0.0
) -> np.ndarray:
    """Mask ``(H, W)`` → the square ``(size, size)`` uint8 frame the optimiser works in.

    ``box`` ``(row0, row1, col0, col1)`` is the region to frame (None: the whole image); it is grown by ``margin``
    × its longer side on each side, padded with backdrop to a square about its centre (aspect ratio kept) and
    framed by :func:`square_mask` (area averaging, half coverage, the mask's holes and no others).
    """
    if size < 1:
        raise ValueError("size must be a positive number of pixels")
    box = box if box is not None else (0, mask.shape[0], 0, mask.shape[1])
    return square_mask(mask, square_box([box], margin), size)


def load_target(path: str | Path, size: int | None = None, cfg: TargetConfig | None = None) -> np.ndarray:
    """Load a still target as a shadow mask ``(H, W)`` uint8, 1 = shadow; with ``size``, framed ``(size, size)``.

    ``cfg`` defaults to ``TargetConfig()``. Raises :class:`TargetError` naming the file for a missing, unreadable
    or non-image file, an empty target (no shadow) or an all-shadow one.
    """
    cfg = cfg or TargetConfig()
    mask = mask_from_grey(read_grey(path), cfg, source=str(path))
    if size is None:
        return mask
    box = shadow_box(mask) if cfg.frame == "shadow" else None
    check_shape_size([box or shadow_box(mask)], str(path))
    framed = square_frame(mask, size, box, cfg.margin if cfg.frame == "shadow" else 0.0)
    if not framed.any():
        raise TargetError(f"the shadow vanishes at {size}×{size} pixels (too small to frame): {path}")
    log.debug("target %s: %d shadow pixels at %d²", path, int(framed.sum()), size)
    return framed
