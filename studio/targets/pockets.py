"""Crease pockets of a still's mask (step 5 of :mod:`studio.targets.images`): under a side light the shade of a
crease (mid-dark skin with the odd black pixel) opens to the outside through a neck, and thresholding cuts it out
of the shape as a ragged notch that no hand casts. :func:`fill_pockets` fills such pockets, never one whose filling
would close an opening into a hole that :func:`~studio.targets.holes.fill_holes` keeps.

Whether a fill closes an opening is decided without recounting the image's holes for every pocket (a 12-megapixel
photo has dozens of pockets along its outline): filling a pocket of the outside backdrop leaves every hole as it
was and can only enclose pieces of that backdrop that touch the pocket; so the pocket's 4-neighbours are labelled,
near it first (one piece there: nothing can close), else within the shape's box (a piece that does not reach the
box's edge is enclosed), and the holes that ``fill_holes`` would keep are summed from each hole's area and core.
A test holds the result equal to the slow reference that counts every hole again for every pocket.

Pure compute (OpenCV morphology and labelling).
"""

from __future__ import annotations

import cv2
import numpy as np

from studio.targets.holes import MIN_CORE_SHARE, MIN_HOLE_AREA, find_holes, hole_areas, is_crease, min_core_area

POCKET_REACH = 0.01  # how far surely-backdrop reaches into mid-dark backdrop, × the shape's longer side [0, 1]
POCKET_NECK = 0.25  # a pocket whose rim lies less than this share along reached backdrop is a crease [0, 1]

_STEP = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))  # a 4-neighbour step (a cross)
_SQUARE = cv2.getStructuringElement(cv2.MORPH_RECT, (3, 3))  # the 8 neighbours


def fill_pockets(
    mask: np.ndarray,
    shade: np.ndarray,
    core_level: float,
    reach: float = POCKET_REACH,
    neck_share: float = POCKET_NECK,
    min_hole_area: float = MIN_HOLE_AREA,
    min_core_share: float = MIN_CORE_SHARE,
) -> np.ndarray:
    """Fill the crease pockets of ``mask`` ``(H, W)`` uint8 (module doc).

    ``shade`` ``(H, W)`` is the shadowness the mask came from and ``core_level`` the level at or below which a pixel
    is surely backdrop. The surely-backdrop regions (opened by a disc of ``2·r − 1`` pixels, so that the odd black
    pixel in a crease's shade is not one) reach ``r = max(1, reach × the shape's longer side)`` pixels into the
    rest of the backdrop; a connected pocket of the mid-dark outside backdrop (not in a hole of ``mask``: an
    opening's shade is :func:`fill_holes`' to judge) that they do not reach (never a surely-backdrop pixel: a binary
    image has none to fill; a black speck left inside is a hole, for :func:`fill_holes`) is filled
    when less than ``neck_share`` of its rim lies along the reached backdrop (it opens to it through a neck) and it
    does not touch the image's border, and it borders the shape, unless filling it would close an opening into a
    hole (a hole that :func:`fill_holes`, given ``min_hole_area`` and ``min_core_share``, keeps; the odd black pixel
    left inside a filled pocket is a crease hole it fills); a soft edge along the outline, which lies along the
    reached backdrop all the way, stays backdrop."""
    back = (mask == 0).astype(np.uint8)
    rows, cols = np.nonzero(mask)
    if reach <= 0 or len(rows) == 0 or not back.any():
        return mask.astype(np.uint8).copy()
    r = max(1, int(round(reach * max(np.ptp(rows), np.ptp(cols)))))
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r - 1, 2 * r - 1))
    sure = shade <= core_level  # (H, W) bool: surely backdrop where it is backdrop
    core = back & sure.astype(np.uint8)
    reached = cv2.morphologyEx(core, cv2.MORPH_OPEN, disc)
    for _ in range(r):  # reach r pixels into the backdrop, through the backdrop
        reached = cv2.dilate(reached, _STEP) & back
    outside = back & (1 - find_holes(mask))  # a hole's mid-dark is fill_holes' to judge, by its core
    n, labels, stats, _ = cv2.connectedComponentsWithStats(outside & (1 - reached) & (1 - core), connectivity=4)
    near_reached, near_shape = cv2.dilate(reached, _STEP) > 0, cv2.dilate(mask.astype(np.uint8), _STEP) > 0
    border = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])  # backdrop seen at the border
    candidates = np.setdiff1d(np.unique(labels[near_shape]), np.append(border, 0))  # only those beside the shape
    out = mask.astype(np.uint8).copy()
    shape_box = [rows.min(), rows.max(), cols.min(), cols.max()]  # first/last row, first/last column of out
    shadow_px = len(rows)  # pixels of out
    holes = None  # (area (K,), core (K,)) of out's holes, found when a pocket first needs them
    for i in candidates:
        x, y, w, h = stats[i, :4]
        box = np.s_[y - 1 : y + h + 1, x - 1 : x + w + 1]  # off the border, so one pixel around is in the image
        pocket = (labels[box] == i).astype(np.uint8)
        rim = (pocket - cv2.erode(pocket, _STEP)) > 0
        if np.count_nonzero(rim & near_reached[box]) >= neck_share * np.count_nonzero(rim):
            continue
        before = out[box].copy()
        out[box] |= pocket
        grown = [min(shape_box[0], y), max(shape_box[1], y + h - 1), min(shape_box[2], x), max(shape_box[3], x + w - 1)]
        added = int(np.count_nonzero(pocket))
        if not _one_piece_near(pocket, out, y - 1, x - 1, max(w, h)):  # the backdrop around it may split
            if holes is None:  # out's holes, without the pocket
                out[box] = before
                holes = hole_areas(out, sure, shape_box)
                out[box] |= pocket
            new = _enclosed(out, pocket, y - 1, x - 1, sure, grown)
            if len(new[0]):
                kept = _opening_px(holes, min_core_area(min_hole_area, shadow_px), min_core_share)
                both = (np.concatenate([holes[0], new[0]]), np.concatenate([holes[1], new[1]]))
                if _opening_px(both, min_core_area(min_hole_area, shadow_px + added), min_core_share) > kept:
                    out[box] = before  # it would close an opening into a hole: left as the threshold cut it
                    continue
                holes = both
        shape_box, shadow_px = grown, shadow_px + added
    return out


def _opening_px(holes: tuple[np.ndarray, np.ndarray], min_area: float, min_core_share: float) -> int:
    """Pixels of the holes (area, core) that ``fill_holes`` keeps as openings at ``min_area`` core pixels."""
    area, core = holes
    return int(area[~is_crease(area, core, min_area, min_core_share)].sum())


def _one_piece_near(pocket: np.ndarray, mask: np.ndarray, top: int, left: int, margin: int) -> bool:
    """Whether the 8-neighbours of ``pocket`` ``(h, w)`` uint8 (at ``top``, ``left`` of ``mask`` ``(H, W)`` uint8,
    in which it is filled) that are backdrop all lie in one 4-connected piece of the backdrop within ``margin`` pixels
    of the pocket's box: then every backdrop path through the pocket can go around it instead, so filling it
    disconnects no backdrop and closes no opening. (False says nothing: the pieces may meet farther away.)"""
    h, w = pocket.shape
    y0, x0 = max(top - margin, 0), max(left - margin, 0)
    near = mask[y0 : top + h + margin, x0 : left + w + margin]
    inside = np.zeros_like(near)
    inside[top - y0 : top - y0 + h, left - x0 : left - x0 + w] = pocket
    ring = (cv2.dilate(inside, _SQUARE) - inside) & (1 - near)
    _, pieces = cv2.connectedComponents(1 - near, connectivity=4)
    return len(np.unique(pieces[ring > 0])) <= 1


def _enclosed(
    mask: np.ndarray, pocket: np.ndarray, top: int, left: int, sure: np.ndarray, shape_box: list[int]
) -> tuple[np.ndarray, np.ndarray]:
    """The holes that filling ``pocket`` ``(h, w)`` (at ``top``, ``left`` of ``mask`` ``(H, W)``, in which it is
    filled) made: (area (K,), core (K,)) of each backdrop piece beside the pocket (its 4-neighbours) that no longer
    reaches the border, found within the shape's box and one pixel around it (``shape_box``: first/last row and
    column of ``mask``'s shape; :func:`~studio.targets.holes.hole_areas`). ``sure`` ``(H, W)`` bool: surely backdrop."""
    h, w = pocket.shape
    (r0, r1, c0, c1), (H, W) = shape_box, mask.shape
    y0, x0 = max(r0 - 1, 0), max(c0 - 1, 0)
    crop = np.s_[y0 : min(r1 + 2, H), x0 : min(c1 + 2, W)]
    _, labels, stats, _ = cv2.connectedComponentsWithStats(1 - mask[crop], connectivity=4)
    side = (cv2.dilate(pocket, _STEP) - pocket) & (1 - mask[top : top + h, left : left + w])
    ids = np.unique(labels[top - y0 : top - y0 + h, left - x0 : left - x0 + w][side > 0])
    ch, cw = labels.shape
    x, y, bw, bh = stats[ids, 0], stats[ids, 1], stats[ids, 2], stats[ids, 3]
    ids = ids[(x > 0) & (y > 0) & (x + bw < cw) & (y + bh < ch)]  # reaching the box's edge: reaching the border
    core = []
    for i in ids:
        sx, sy, sw, sh = stats[i, :4]
        sub = np.s_[sy : sy + sh, sx : sx + sw]
        core.append(np.count_nonzero((labels[sub] == i) & sure[crop][sub]))
    return stats[ids, cv2.CC_STAT_AREA].astype(np.int64), np.asarray(core, dtype=np.int64)
