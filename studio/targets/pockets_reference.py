"""The slow reference of :func:`studio.targets.pockets.fill_pockets` (tests hold them equal; ``bench_targets.py``
times both): the same pockets, and for every one that passes the neck rule every hole of the image counted again
(``fill_holes`` then ``find_holes``), with the pocket and without it. Pure compute."""

from __future__ import annotations

import cv2
import numpy as np

from studio.targets.holes import fill_holes, find_holes


def fill_pockets_slowly(
    mask: np.ndarray,
    shade: np.ndarray,
    core_level: float,
    reach: float,
    neck_share: float,
    min_hole_area: float,
    min_core_share: float,
) -> tuple[np.ndarray, int]:
    """``fill_pockets``' answer ``(H, W)`` uint8 and how many pockets it refused (they would close an opening)."""
    back = (mask == 0).astype(np.uint8)
    rows, cols = np.nonzero(mask)
    if reach <= 0 or len(rows) == 0 or not back.any():
        return mask.astype(np.uint8).copy(), 0
    r = max(1, int(round(reach * max(np.ptp(rows), np.ptp(cols)))))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r - 1, 2 * r - 1))
    step = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    core = back & (shade <= core_level).astype(np.uint8)
    reached = cv2.morphologyEx(core, cv2.MORPH_OPEN, disc)
    for _ in range(r):
        reached = cv2.dilate(reached, step) & back
    outside = back & (1 - find_holes(mask))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(outside & (1 - reached) & (1 - core), connectivity=4)
    out = mask.astype(np.uint8).copy()

    def openings(m):
        return np.count_nonzero(find_holes(fill_holes(m, shade, core_level, min_hole_area, min_core_share)))

    near_reached, near_shape = cv2.dilate(reached, step) > 0, cv2.dilate(mask.astype(np.uint8), step) > 0
    border = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])
    refused = 0
    for i in np.setdiff1d(np.unique(labels[near_shape]), np.append(border, 0)):
        x, y, w, h = stats[i, :4]
        box = np.s_[y - 1 : y + h + 1, x - 1 : x + w + 1]
        pocket = (labels[box] == i).astype(np.uint8)
        rim = (pocket - cv2.erode(pocket, step)) > 0
        if np.count_nonzero(rim & near_reached[box]) >= neck_share * np.count_nonzero(rim):
            continue
        trial = out.copy()
        trial[box] |= pocket
        if openings(trial) <= openings(out):
            out = trial
        else:
            refused += 1
    return out, refused
