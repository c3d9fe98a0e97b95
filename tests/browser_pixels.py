"""What the pixels of the studio in a browser must show (tests/test_browser.py): each judge takes a screenshot as
``(H, W, 3)`` uint8 RGB and says whether a person would see the thing drawn, so a viewer that draws nothing or a
preview coloured the wrong way round fails."""

from __future__ import annotations

import cv2
import numpy as np


def tinted(rgb: np.ndarray) -> np.ndarray:
    """Pixels of a grey picture tinted with the mask colour (``widgets.images.MASK_RGB``, orange): ``(H, W)`` bool."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return (r - b > 60) & (g - b > 25)


def drawn_rig(rgb: np.ndarray) -> tuple[bool, dict]:
    """Whether a screenshot ``(H, W, 3)`` of the meshcat scene shows the rig, not meshcat's empty default scene (sky,
    grid, axes): the lit backdrop (near-white, ≥ 2 % of the view), the hand's shadow on it (dark grey pixels inside
    the backdrop's box, ≥ 3 % of its white ones) and the light (yellow)."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    lo, hi = np.minimum(np.minimum(r, g), b), np.maximum(np.maximum(r, g), b)
    white, grey = (lo > 215) & (hi - lo < 25), (hi > 20) & (hi < 100) & (hi - lo < 25)
    yellow = (r > 200) & (g > 160) & (b < 120)
    facts = {"white": round(float(white.mean()), 4), "yellow": round(float(yellow.mean()), 4), "shadow": 0.0}
    if white.any():
        ys, xs = np.nonzero(white)
        box = grey[ys.min() : ys.max() + 1, xs.min() : xs.max() + 1]
        facts["shadow"] = round(float(box.sum() / white.sum()), 4)
    return facts["white"] >= 0.02 and facts["yellow"] >= 0.001 and facts["shadow"] >= 0.03, facts


def red(rgb: np.ndarray) -> np.ndarray:
    """Red-dominant pixels (a latched E-STOP's colour): ``(H, W)`` bool."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return (r >= 100) & (r > 2 * g) & (r > 2 * b)


def shadow_tile(frame: np.ndarray, side: int = 128) -> np.ndarray:
    """The shadow column of a show player's picture ``(H, W, 3)`` as ``(side, side, 3)``: its frames are source |
    target | shadow, three square tiles side by side (``studio.review.video_review.side_by_side_frame``), so the
    shadow is the last ``H`` columns however the page scales the canvas (a margin left out: the gap before it, the
    scaling's blur); resized, so two pictures compare pixel by pixel whatever size each was drawn at."""
    h, w = frame.shape[:2]
    m = max(2, h // 20)
    return cv2.resize(frame[m : h - m, w - h + m : w - m], (side, side), interpolation=cv2.INTER_AREA)


def over_the_shape(preview: np.ndarray, stored: np.ndarray) -> tuple[float, float]:
    """How the Targets preview ``(H, W, 3)`` tints the stored mask ``(S, S)`` {0, 1}, scaled to it (the horse's
    preview and its stored masks share one framing, the padded square): → (share of the shape's pixels tinted, share
    of the rest tinted: the backdrop and the black bars)."""
    h, w = preview.shape[:2]
    shape = cv2.resize(np.asarray(stored, np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    tint = tinted(preview)
    return float(tint[shape].mean()), float(tint[~shape].mean())


def drawn_recording(rgb: np.ndarray) -> tuple[bool, dict]:
    """Whether a Rerun canvas draws the project's recording: varied pixels, and the target view's image, a black
    shape on a white backdrop (a large black blob ringed by white), which neither a blank canvas nor Rerun's welcome
    page (text, a few small pictures) has, in its light theme or its dark one. → (ok, the measurements)."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    h, w = grey.shape
    n, _, stats, _ = cv2.connectedComponentsWithStats((grey < 40).astype(np.uint8), connectivity=4)
    shapes = 0
    for x, y, bw, bh, area in stats[1:]:
        if area < 0.003 * h * w or bw > w / 2 or bh > h / 2 or bw < 20 or bh < 20:
            continue  # a glyph, a line, or the dark theme's background
        x0, y0, x1, y1 = max(0, x - 8), max(0, y - 8), min(w, x + bw + 8), min(h, y + bh + 8)
        ring = np.ones((y1 - y0, x1 - x0), bool)
        ring[y - y0 : y - y0 + bh, x - x0 : x - x0 + bw] = False
        shapes += bool((grey[y0:y1, x0:x1][ring] > 225).mean() > 0.6)
    facts = {"std": round(float(grey.std()), 1), "shapes_on_white": shapes}
    return facts["std"] > 20 and shapes >= 1, facts


def plotted(rgb: np.ndarray, colour: tuple[int, int, int], tolerance: int = 40) -> tuple[bool, dict]:
    """Whether a Rerun canvas of the project's layout (``studio.review.blueprint``: the plots under the images in the
    left 60 %) draws a series line of ``colour`` (RGB) in its plots: ≥ 30 pixels of it, spread over ≥ 20 columns.
    → (ok, the measurements)."""
    h, w = rgb.shape[:2]
    plots = rgb[int(0.5 * h) : int(0.93 * h), : int(0.6 * w)].astype(int)
    ys, xs = np.nonzero((np.abs(plots - np.array(colour)) <= tolerance).all(axis=-1))
    facts = {"pixels": int(len(xs)), "columns": int(len(set(xs.tolist()))),
             "left_columns": int(len(set(xs[xs < plots.shape[1] / 3].tolist())))}  # fmt: skip
    return facts["pixels"] >= 30 and facts["columns"] >= 20, facts
