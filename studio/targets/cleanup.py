"""Cleaning a thresholded photograph of a shadow: ruled lines and specks that are backdrop, not shape.

Photographed silhouettes (Muybridge's plates) stand on a ruled backdrop: thin dark lines across the frame that a
threshold keeps and that touch the feet, so keeping the largest piece keeps them too. Two steps remove them
before the still-target steps (pieces, holes) of :mod:`studio.targets.images` run:

1. **ruled lines**: the pixels whose run of shadow across one axis is thin (``thickness`` × the shorter side)
   and that form, along that axis, a run of such thin pixels that is long (``length`` × the longer side). A tail
   or a leg is thin only over its own length, shorter than a rule across the frame; where a rule meets a foot
   the run across is the foot's, so the rule stops there and the foot stays whole;
2. **specks and hairlines**: an opening by a disc of ``radius`` pixels, then a dilation by the same disc inside
   the thresholded mask, so that the outline of what survives comes back exactly and only thin loose bits go.
"""

from __future__ import annotations

import cv2
import numpy as np


def run_lengths(mask: np.ndarray, axis: int) -> np.ndarray:
    """For every pixel of ``mask`` ``(H, W)``, the length of its run of shadow along ``axis`` (1: its row, 0: its
    column); 0 on the backdrop. ``(H, W)`` int64."""
    m = np.asarray(mask, dtype=bool)
    if axis == 0:
        return run_lengths(m.T, 1).T
    h, w = m.shape
    d = np.diff(np.pad(m, ((0, 0), (1, 1))).astype(np.int8), axis=1)
    starts = np.argwhere(d == 1)  # row-major, paired with the ends
    ends = np.argwhere(d == -1)
    lengths = ends[:, 1] - starts[:, 1]
    out = np.zeros(h * w, np.int64)
    if len(lengths):
        first = starts[:, 0] * w + starts[:, 1]
        offset = np.arange(lengths.sum()) - np.repeat(np.cumsum(lengths) - lengths, lengths)
        out[np.repeat(first, lengths) + offset] = np.repeat(lengths, lengths)
    return out.reshape(h, w)


def ruled_lines(mask: np.ndarray, length: float = 0.3, thickness: float = 0.035) -> np.ndarray:
    """The pixels of ``mask`` ``(H, W)`` on long thin horizontal or vertical lines (module doc, step 1), uint8."""
    if length <= 0:
        return np.zeros(mask.shape, np.uint8)
    long_px = max(2, int(round(length * max(mask.shape))))
    thin_px = max(1, int(round(thickness * min(mask.shape))))
    m = np.asarray(mask, dtype=bool)
    flat = m & (run_lengths(m, 0) <= thin_px)  # pixels in a thin run down their column
    tall = m & (run_lengths(m, 1) <= thin_px)  # pixels in a thin run along their row
    lines = (run_lengths(flat, 1) >= long_px) | (run_lengths(tall, 0) >= long_px)
    return lines.astype(np.uint8)


def remove_specks(mask: np.ndarray, radius: int) -> np.ndarray:
    """``mask`` ``(H, W)`` without the parts thinner than a disc of ``radius`` px (module doc, step 2), uint8."""
    mask = np.asarray(mask, dtype=np.uint8)
    if radius < 1:
        return mask.copy()
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    opened = cv2.morphologyEx(mask, cv2.MORPH_OPEN, disc)
    return mask & cv2.dilate(opened, disc)


def clean_shadow(
    mask: np.ndarray, line_length: float = 0.3, line_thickness: float = 0.035, speck_radius: float = 0.01
) -> np.ndarray:
    """Both steps on a thresholded mask ``(H, W)``: ruled lines, then specks (``speck_radius`` × the shorter side,
    px); uint8, a subset of ``mask``."""
    mask = np.asarray(mask, dtype=np.uint8)
    kept = mask & (1 - ruled_lines(mask, line_length, line_thickness))
    return remove_specks(kept, int(round(speck_radius * min(mask.shape))))
