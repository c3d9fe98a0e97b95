"""Holes of a shadow mask (DESIGN §4: a still's expressive region): finding them, filling the creases that are not
openings, and framing a mask without closing a gap into a hole it does not have.

A **hole** is a region of backdrop not 4-connected to the image border (:func:`find_holes`). Two steps make holes
that the target does not have, and this module undoes both:

- *Creases* (step 5 of :mod:`studio.targets.images`): the dark creases between the fingers of a fist enclose
  mid-dark skin, not backdrop; :func:`fill_holes` fills every hole whose surely-backdrop core is too small. Under a
  side light a crease's shade also opens to the outside through a neck (signer 2's ``right`` letters: `g`, `q`,
  `v`, `x`), a pocket rather than a hole; :func:`fill_pockets` fills the mid-dark pockets that surely-backdrop does
  not reach.
- *Framing*: the optimiser's frame (128² or 256²) is the source mask averaged over areas and thresholded at half
  coverage, so a gap narrower than a frame pixel closes: the backdrop between a horse's legs, open to the outside
  at the source through a gap of a few source pixels, becomes a hole of 41 frame pixels; a camel's, cattle's or an
  ASL "h"'s outline gains holes of 1–20 pixels the same way. The holes' expressive term then weighs a region the
  image does not have. :func:`threshold_keeping_gaps` thresholds the same coverage but opens every hole that no
  source hole lies under, along the path of least shadow coverage to the outside backdrop (a pixel or a few, all
  of them pixels the gap crosses), so the framed mask has exactly the source's openings. On the 12 MPEG-7 and 26
  ASL held-out images 5 of the 6 framed targets with holes had only such false holes (the ASL "o" alone has an
  opening at the source).

Pure compute (OpenCV labelling, SciPy's Dijkstra).
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

_BACKDROP_STEP = 1e-9  # the cost of crossing a backdrop pixel (csgraph drops zero-weight edges)
MIN_HOLE_AREA = 0.015  # smallest real opening's core: < 1 → fraction of the shadow area, ≥ 1 → pixels
MIN_CORE_SHARE = 0.3  # a hole whose core is less than this share of its area is a crease [0, 1]
POCKET_REACH = 0.01  # how far surely-backdrop reaches into mid-dark backdrop, × the shape's longer side [0, 1]
POCKET_NECK = 0.25  # a pocket whose rim lies less than this share along reached backdrop is a crease [0, 1]


def hole_labels(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """4-connected backdrop regions of ``mask`` ``(H, W)``: labels ``(H, W)`` and the ids of those not touching the
    border (the holes)."""
    n, labels = cv2.connectedComponents((mask == 0).astype(np.uint8), connectivity=4)  # 0: the shadow
    border = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    return labels, np.setdiff1d(np.arange(1, n), border)


def find_holes(mask: np.ndarray) -> np.ndarray:
    """Holes of a shadow mask ``(H, W)``: backdrop pixels not 4-connected to the image border, ``(H, W)`` uint8."""
    labels, ids = hole_labels(mask)
    return np.isin(labels, ids).astype(np.uint8)


def fill_holes(
    mask: np.ndarray,
    shade: np.ndarray | None = None,
    core_level: float = 0.0,
    min_hole_area: float = MIN_HOLE_AREA,
    min_core_share: float = MIN_CORE_SHARE,
) -> np.ndarray:
    """Fill the crease holes of ``mask`` ``(H, W)`` and keep the real openings (:mod:`studio.targets.images`, step 5).

    ``shade`` is the shadowness ``(H, W)`` the mask came from (None: the mask is all there is, every hole pixel is
    core); ``core_level`` the shadowness at or below which a pixel is surely backdrop; a hole is an opening when its
    core covers at least ``min_hole_area`` (< 1: a share of the shadow area; ≥ 1: pixels) and at least
    ``min_core_share`` of the hole (:class:`~studio.targets.images.TargetConfig`).
    """
    labels, ids = hole_labels(mask)
    out = mask.astype(np.uint8).copy()
    if len(ids) == 0:
        return out
    area = np.bincount(labels.ravel(), minlength=labels.max() + 1)
    core_px = (labels if shade is None else np.where(shade <= core_level, labels, 0)).ravel()
    core = np.bincount(core_px, minlength=labels.max() + 1)
    min_area = min_hole_area * int(mask.sum()) if min_hole_area < 1 else min_hole_area
    fill = [i for i in ids if core[i] < min_area or core[i] < min_core_share * area[i]]
    out[np.isin(labels, fill)] = 1
    return out


def fill_pockets(
    mask: np.ndarray,
    shade: np.ndarray,
    core_level: float,
    reach: float = POCKET_REACH,
    neck_share: float = POCKET_NECK,
    min_hole_area: float = MIN_HOLE_AREA,
    min_core_share: float = MIN_CORE_SHARE,
) -> np.ndarray:
    """Fill the crease pockets of ``mask`` ``(H, W)`` uint8 (:mod:`studio.targets.images`, step 5; module doc).

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
    step = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (3, 3))
    core = back & (shade <= core_level).astype(np.uint8)
    reached = cv2.morphologyEx(core, cv2.MORPH_OPEN, disc)
    for _ in range(r):  # reach r pixels into the backdrop, through the backdrop
        reached = cv2.dilate(reached, step) & back
    outside = back & (1 - find_holes(mask))  # a hole's mid-dark is fill_holes' to judge, by its core
    n, labels, stats, _ = cv2.connectedComponentsWithStats(outside & (1 - reached) & (1 - core), connectivity=4)
    out = mask.astype(np.uint8).copy()

    def openings(m: np.ndarray) -> np.ndarray:  # the holes that fill_holes keeps: real openings
        return find_holes(fill_holes(m, shade, core_level, min_hole_area, min_core_share))

    near_reached, near_shape = cv2.dilate(reached, step) > 0, cv2.dilate(mask.astype(np.uint8), step) > 0
    border = np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])  # backdrop seen at the border
    candidates = np.setdiff1d(np.unique(labels[near_shape]), np.append(border, 0))  # only those beside the shape
    kept = None  # the opening pixels of out, counted when a pocket first needs them
    for i in candidates:
        x, y, w, h = stats[i, :4]
        box = np.s_[y - 1 : y + h + 1, x - 1 : x + w + 1]  # off the border, so one pixel around is in the image
        pocket = (labels[box] == i).astype(np.uint8)
        rim = (pocket - cv2.erode(pocket, step)) > 0
        if np.count_nonzero(rim & near_reached[box]) >= neck_share * np.count_nonzero(rim):
            continue
        trial = out.copy()
        trial[box] |= pocket
        if _one_piece_around(pocket, trial[box]):  # every path through it goes around it: no hole can close
            out, kept = trial, None  # (the shadow grew: fill_holes' area rule is counted again when needed)
            continue
        kept = np.count_nonzero(openings(out)) if kept is None else kept
        now = np.count_nonzero(openings(trial))
        if now <= kept:  # never closes an opening into a hole
            out, kept = trial, now
    return out


def _one_piece_around(pocket: np.ndarray, mask: np.ndarray) -> bool:
    """Whether the backdrop of ``mask`` ``(h, w)`` around ``pocket`` ``(h, w)`` (both uint8, a box one pixel wider
    than the pocket; the ring of its 8 neighbours) is one 4-connected piece: then a backdrop path through the pocket
    can go around it instead, so filling the pocket disconnects no backdrop and closes no opening."""
    square = cv2.getStructuringElement(cv2.MORPH_RECT, (3, 3))
    ring = (cv2.dilate(pocket, square) - pocket) & (1 - mask)
    return cv2.connectedComponents(ring, connectivity=4)[0] <= 2  # the label 0 and at most one piece


def _grid_graph(cost: np.ndarray) -> coo_matrix:
    """4-neighbour grid over ``cost`` ``(H, W)``: stepping onto a pixel costs its value."""
    h, w = cost.shape
    idx = np.arange(h * w).reshape(h, w)
    pairs = [(idx[:, :-1], idx[:, 1:]), (idx[:, 1:], idx[:, :-1]), (idx[:-1], idx[1:]), (idx[1:], idx[:-1])]
    src = np.concatenate([a.ravel() for a, _ in pairs])
    dst = np.concatenate([b.ravel() for _, b in pairs])
    return coo_matrix((cost.ravel()[dst], (src, dst)), shape=(h * w, h * w)).tocsr()


def _false_holes(mask: np.ndarray, hole_cover: np.ndarray) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """``mask``'s hole labels and ids, and the ids of the holes with no source hole under them."""
    labels, ids = hole_labels(mask)
    return labels, ids, [int(i) for i in ids if not np.any(hole_cover[labels == i] > 0)]


def threshold_keeping_gaps(cover: np.ndarray, hole_cover: np.ndarray, level: float = 0.5) -> np.ndarray:
    """A framed mask ``(S, S)`` uint8 with the source's openings and no others.

    ``cover`` ``(S, S)`` is the share of each frame pixel the source's shadow covers, ``hole_cover`` the share its
    holes cover (both area averages of the same crop); shadow where ``cover ≥ level``, then every hole of that mask
    with no source hole under it (``hole_cover`` 0 throughout) is opened: its cheapest 4-connected path to the
    backdrop outside (each shadow pixel crossed costs its coverage) becomes backdrop (module doc)."""
    cover = np.asarray(cover, np.float64)
    mask = (cover >= level).astype(np.uint8)
    labels, ids, false = _false_holes(mask, hole_cover)
    for _ in range(len(false)):  # one opening a round (an opening may run through another false hole)
        if not false:
            break
        outside = ((mask == 0) & ~np.isin(labels, ids)).ravel()
        if not outside.any():  # the shadow covers the frame's whole border: nowhere to open to
            break
        cost = np.where(mask == 1, np.maximum(cover, _BACKDROP_STEP), _BACKDROP_STEP)
        start = np.flatnonzero(labels.ravel() == false[0])
        dist, pred = dijkstra(_grid_graph(cost), indices=start, min_only=True, return_predecessors=True)[:2]
        ends = np.flatnonzero(outside)
        node = int(ends[np.argmin(dist[ends])])
        while node >= 0 and labels.flat[node] != false[0]:  # back along the path to the hole
            mask.flat[node] = 0
            node = int(pred[node])
        labels, ids, false = _false_holes(mask, hole_cover)
    return mask
