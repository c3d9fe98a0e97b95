"""Holes of a shadow mask (DESIGN §4: a still's expressive region): finding them, filling the creases that are not
openings, and framing a mask without closing a gap into a hole it does not have.

A **hole** is a region of backdrop not 4-connected to the image border (:func:`find_holes`). Two steps make holes
that the target does not have, and this module undoes both:

- *Creases* (step 5 of :mod:`studio.targets.images`): the dark creases between the fingers of a fist enclose
  mid-dark skin, not backdrop; :func:`fill_holes` fills every hole whose surely-backdrop core is too small. Under a
  side light a crease's shade also opens to the outside through a neck (signer 2's ``right`` letters: `g`, `q`,
  `v`, `x`), a pocket rather than a hole; :func:`studio.targets.pockets.fill_pockets` fills the mid-dark pockets
  that surely-backdrop does not reach.
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
    crease = is_crease(area[ids], core[ids], min_core_area(min_hole_area, int(mask.sum())), min_core_share)
    out[np.isin(labels, ids[crease])] = 1
    return out


def min_core_area(min_hole_area: float, shadow_px: int) -> float:
    """The core pixels an opening needs (``min_hole_area``: < 1 a share of the ``shadow_px`` pixels of shadow)."""
    return min_hole_area * shadow_px if min_hole_area < 1 else min_hole_area


def is_crease(area: np.ndarray, core: np.ndarray, min_area: float, min_core_share: float) -> np.ndarray:
    """Which holes ``(K,)`` of ``area`` pixels with ``core`` surely-backdrop pixels :func:`fill_holes` fills: a core
    under ``min_area`` pixels or under ``min_core_share`` of the hole."""
    return (core < min_area) | (core < min_core_share * area)


def hole_areas(mask: np.ndarray, sure: np.ndarray, shape_box: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """(area (K,), core (K,)) in pixels of each hole of ``mask`` ``(H, W)``, its core the pixels of ``sure`` ``(H, W)``
    bool (surely backdrop). Found within ``shape_box`` (first/last row, first/last column of the shape) and one pixel
    around it: every hole lies inside, and backdrop on that ring reaches the image's border around the box."""
    (r0, r1, c0, c1), (h, w) = shape_box, mask.shape
    crop = np.s_[max(r0 - 1, 0) : min(r1 + 2, h), max(c0 - 1, 0) : min(c1 + 2, w)]
    n, labels, stats, _ = cv2.connectedComponentsWithStats((mask[crop] == 0).astype(np.uint8), connectivity=4)
    ch, cw = labels.shape
    x, y, bw, bh = stats[:, 0], stats[:, 1], stats[:, 2], stats[:, 3]
    ids = np.flatnonzero((x > 0) & (y > 0) & (x + bw < cw) & (y + bh < ch))
    ids = ids[ids > 0]  # label 0: the shadow
    core = np.bincount(labels[sure[crop]], minlength=n)
    return stats[ids, cv2.CC_STAT_AREA].astype(np.int64), core[ids].astype(np.int64)


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
