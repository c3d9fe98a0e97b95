"""The evidence :mod:`studio.targets.segment` weighs for each pixel of a frame, and the graph cut that decides.

Every cue is a log-likelihood ratio map ``(h, w)`` float (positive = object), at the work resolution:

* :func:`colour_llr` — global colour histograms of the object and of its surroundings (``bins``³ RGB cells,
  Gaussian-smoothed in colour);
* :func:`local_colour_llr` — the same counts kept per spatial cell as well (a bilateral grid over x, y and colour,
  blurred in both): a colour is the object's only *near where the object had it*, which tells a black swan from
  its dark reflection a few pixels away;
* :func:`motion_llr` — the dense flow against two homographies fitted by RANSAC, one to the background around the
  object and one to the object: a pixel that moves like the object and not like the background is object. The cue
  comes with its own reliability, measured on the band just outside the object (textureless water takes the
  object's flow, so there it is switched off);
* :func:`box_motion` — the first frame's motion cue from a box: the flow to a few later frames against the
  homography of everything outside the box, in units of the background's own residual, occlusions left out by a
  forward-backward check.

:func:`graph_cut` finds the labelling that minimises the summed unary costs plus a contrast-sensitive Potts term
(8-connected) by max-flow (``scipy.sparse.csgraph.maximum_flow``, Dinic).
"""

from __future__ import annotations

import cv2
import numpy as np
import scipy.ndimage as ndi
import scipy.sparse as sp
from scipy.sparse.csgraph import breadth_first_order, maximum_flow

HARD = 1000.0  # unary magnitude of a pixel whose label is given (definite background)
_SCALE = 64.0  # max-flow capacities are integers: costs × this, rounded


def disk(radius: int) -> np.ndarray:
    """An elliptic structuring element of the given radius (px)."""
    r = max(int(radius), 0)
    return cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))


def ring(mask: np.ndarray, width: int) -> np.ndarray:
    """``(h, w)`` bool: the band of ``width`` px just outside ``mask`` (uint8 {0, 1})."""
    return (cv2.dilate(mask, disk(max(width, 1))) > 0) & (mask == 0)


def graph_cut(unary: np.ndarray, image: np.ndarray, smoothness: float) -> np.ndarray:
    """Binary labelling ``(h, w)`` bool (True = object) minimising ``Σ unary costs + smoothness · Σ Potts``.

    ``unary`` ``(h, w)``: cost(background) − cost(object), so positive prefers the object. ``image`` ``(h, w, 3)``
    (Lab) gives the contrast term ``exp(−β‖ΔI‖²)``, β = 1 / (2 ⟨‖ΔI‖²⟩), diagonal neighbours weighted 1/√2.
    """
    h, w = unary.shape
    n = h * w
    src, snk = n, n + 1
    idx = np.arange(n).reshape(h, w)
    img = image.astype(np.float32)
    pairs = [
        (idx[:, :-1], idx[:, 1:], img[:, :-1] - img[:, 1:], 1.0),
        (idx[:-1, :], idx[1:, :], img[:-1] - img[1:], 1.0),
        (idx[:-1, :-1], idx[1:, 1:], img[:-1, :-1] - img[1:, 1:], 2**-0.5),
        (idx[:-1, 1:], idx[1:, :-1], img[:-1, 1:] - img[1:, :-1], 2**-0.5),
    ]
    d2 = [(d**2).sum(-1).ravel() for _, _, d, _ in pairs]
    mean_d2 = float(np.mean(np.concatenate(d2))) if n > 1 else 0.0
    beta = 1.0 / (2.0 * mean_d2 + 1e-6)
    rows, cols, caps = [], [], []
    for (a, b, _, f), d in zip(pairs, d2):
        wgt = smoothness * f * np.exp(-beta * d)
        rows += [a.ravel(), b.ravel()]
        cols += [b.ravel(), a.ravel()]
        caps += [wgt, wgt]
    u = unary.ravel()
    pos = u > 0
    rows += [np.full(int(pos.sum()), src), idx.ravel()[~pos]]
    cols += [idx.ravel()[pos], np.full(int((~pos).sum()), snk)]
    caps += [u[pos], -u[~pos]]
    cap = np.round(np.concatenate(caps) * _SCALE).astype(np.int32)
    graph = sp.csr_matrix((cap, (np.concatenate(rows), np.concatenate(cols))), shape=(n + 2, n + 2))
    flow = maximum_flow(graph, src, snk).flow
    residual = (graph - flow).tocsr()
    residual.data = (residual.data > 0).astype(np.int8)
    residual.eliminate_zeros()
    reach = breadth_first_order(residual, src, directed=True, return_predecessors=False)
    label = np.zeros(n + 2, bool)
    label[reach] = True
    return label[:n].reshape(h, w)


def colour_index(rgb: np.ndarray, bins: int) -> np.ndarray:
    """``(h, w, 3)`` uint8 RGB → ``(h, w)`` int32 index of its cell among ``bins``³ colour cells."""
    q = (rgb.astype(np.int32) * bins) // 256
    return (q[..., 0] * bins + q[..., 1]) * bins + q[..., 2]


def colour_hist(index: np.ndarray, select: np.ndarray, bins: int) -> np.ndarray:
    """Counts ``(bins, bins, bins)`` of the selected pixels' colour cells, smoothed by one cell in colour."""
    counts = np.bincount(index[select], minlength=bins**3).astype(np.float64).reshape(bins, bins, bins)
    return ndi.gaussian_filter(counts, 1.0, mode="constant")


def _log_density(hist: np.ndarray) -> np.ndarray:
    p = hist + 1e-3 * hist.sum() / hist.size + 1e-9  # a floor: a colour never seen is unlikely, not impossible
    return np.log(p / p.sum()).ravel()


def colour_llr(index: np.ndarray, fg_hist: np.ndarray, bg_hist: np.ndarray, clip: float) -> np.ndarray:
    """``log p(colour | object) − log p(colour | background)`` per pixel, clipped to ±clip."""
    return np.clip(_log_density(fg_hist)[index] - _log_density(bg_hist)[index], -clip, clip)


def local_colour_llr(
    rgb: np.ndarray,
    mask: np.ndarray,
    size: float,
    cell: float,
    bins: int,
    blur: tuple[float, float],
    eps: float,
    clip: float,
    guard: float = 0.04,
) -> np.ndarray:
    """Bilateral-grid colour evidence ``(h, w)`` for ``rgb`` ``(h, w, 3)`` given a guess ``mask`` ``(h, w)`` {0, 1}.

    The guess's core (eroded by 4 % of the object ``size`` = √area) and its outside (dilated the same) are counted
    in cells of ``cell × size`` px and ``bins``³ colours, blurred by ``blur`` = (space, colour) cells; the ratio of
    the counts (plus ``eps``) at a pixel's cell is its evidence, clipped to ±clip.
    """
    h, w = mask.shape
    side = max(4.0, cell * size)
    yy, xx = np.mgrid[0:h, 0:w]
    iy, ix = (yy / side).astype(np.int32), (xx / side).astype(np.int32)
    ny, nx = int(iy.max()) + 1, int(ix.max()) + 1
    idx = (iy * nx + ix) * bins**3 + colour_index(rgb, bins)
    r = max(1, int(guard * size))
    inside, outside = cv2.erode(mask, disk(r)) > 0, cv2.dilate(mask, disk(r)) == 0
    shape, sigma = (ny, nx, bins, bins, bins), (blur[0],) * 2 + (blur[1],) * 3
    n = ny * nx * bins**3
    fg, bg = (
        ndi.gaussian_filter(
            np.bincount(idx[sel], minlength=n).reshape(shape).astype(np.float32), sigma, mode="constant"
        )
        for sel in (inside, outside)
    )
    return np.clip(np.log((fg.ravel()[idx] + eps) / (bg.ravel()[idx] + eps)), -clip, clip)


def fit_homography(flow: np.ndarray, select: np.ndarray, step: int = 3) -> np.ndarray | None:
    """RANSAC homography ``(3, 3)`` mapping pixels to pixel + flow over ``select`` (every ``step``-th pixel)."""
    s = select[::step, ::step]
    if s.sum() < 12:
        return None
    h, w = select.shape
    gy, gx = np.mgrid[0:h:step, 0:w:step].astype(np.float32)
    p0 = np.stack([gx[s], gy[s]], 1)
    hom, _ = cv2.findHomography(p0, p0 + flow[::step, ::step][s], cv2.RANSAC, 1.0)
    return hom


def homography_flow(hom: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The flow ``(h, w, 2)`` a homography ``(3, 3)`` gives every pixel."""
    gy, gx = np.mgrid[0 : shape[0], 0 : shape[1]].astype(np.float64)
    p = np.stack([gx, gy, np.ones_like(gx)], -1) @ hom.T
    return (p[..., :2] / p[..., 2:3] - np.stack([gx, gy], -1)).astype(np.float32)


def motion_llr(
    flow: np.ndarray,
    mask: np.ndarray,
    size: float,
    noise: float,
    clip: float,
    fp_low: float,
    fp_high: float,
) -> tuple[np.ndarray | None, float]:
    """Motion evidence ``(h, w)`` (or None) and its reliability in [0, 1], from ``flow`` ``(h, w, 2)`` px and the
    object's predicted ``mask`` ``(h, w)`` {0, 1} in the same frame.

    ``d_bg``, ``d_obj``: distances of each pixel's flow to the background's and the object's homography, capped at
    4 σ (σ = the background's robust residual, at least ``noise`` px); evidence ``(d_bg² − d_obj²) / 2σ²`` ±clip.
    Reliability falls from 1 to 0 as the share of the band outside the object that the cue calls object rises
    from ``fp_low`` to ``fp_high``, and is 0 when the two motions are within 1 σ of each other.
    """
    r = max(2, int(0.1 * size))
    bg_sel = cv2.dilate(mask, disk(r)) == 0
    obj_sel = cv2.erode(mask, disk(max(1, r // 2))) > 0
    hb, ho = fit_homography(flow, bg_sel), fit_homography(flow, obj_sel)
    if hb is None or ho is None:
        return None, 0.0
    fb, fo = homography_flow(hb, mask.shape), homography_flow(ho, mask.shape)
    d_bg, d_obj = np.linalg.norm(flow - fb, axis=-1), np.linalg.norm(flow - fo, axis=-1)
    sigma = max(noise, 1.4826 * float(np.median(d_bg[bg_sel])))
    separation = float(np.median(np.linalg.norm(fo - fb, axis=-1)[obj_sel])) / sigma
    cap = 4 * sigma
    llr = np.clip((np.minimum(d_bg, cap) ** 2 - np.minimum(d_obj, cap) ** 2) / (2 * sigma**2), -clip, clip)
    false_pos = float(np.mean(llr[ring(mask, r)] > 1.0))
    true_pos = float(np.mean(llr[obj_sel] > 1.0))
    reliability = (
        np.clip((separation - 1.0) / 2.0, 0, 1)
        * np.clip((fp_high - false_pos) / (fp_high - fp_low), 0, 1)
        * np.clip((true_pos - 0.5) / 0.3, 0, 1)
    )
    return llr, float(reliability)


def box_motion(flows: list[tuple[np.ndarray, np.ndarray]], box: tuple[int, int, int, int]) -> np.ndarray:
    """First-frame motion residual ``(h, w)`` (NaN where unknown) from ``flows`` = [(0→k, k→0)] and a ``box``.

    The residual of each pixel's flow 0→k against the homography of everything outside the box, divided by the
    90th percentile of that residual outside the box (+0.2 px), averaged over k; a pixel whose forward and
    backward flows disagree (occluded or uncovered) is NaN for that k.
    """
    x, y, bw, bh = box
    h, w = flows[0][0].shape[:2]
    outside = np.ones((h, w), bool)
    outside[y : y + bh, x : x + bw] = False
    gy, gx = np.mgrid[0:h, 0:w].astype(np.float32)
    zs = []
    for fwd, bwd in flows:
        hom = fit_homography(fwd, outside)
        if hom is None:
            continue
        resid = np.linalg.norm(fwd - homography_flow(hom, (h, w)), axis=-1)
        z = resid / (np.percentile(resid[outside], 90) + 0.2)
        back = cv2.remap(bwd, gx + fwd[..., 0], gy + fwd[..., 1], cv2.INTER_LINEAR)
        z[np.linalg.norm(fwd + back, axis=-1) > 1.0 + 0.1 * np.linalg.norm(fwd, axis=-1)] = np.nan
        zs.append(z)
    if not zs:
        return np.full((h, w), np.nan, np.float32)
    stack = np.stack(zs)
    known = ~np.isnan(stack)
    return np.where(known.any(0), np.nansum(stack, 0) / np.maximum(known.sum(0), 1), np.nan)


def keep_components(mask: np.ndarray, ref: np.ndarray | None, min_share: float) -> np.ndarray:
    """``mask`` {0, 1} without specks: 8-connected pieces of at least ``min_share`` of the largest, and (with a
    ``ref`` prediction) that lie at least 20 % inside it (the most overlapping piece is always kept)."""
    n, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return mask.astype(np.uint8)
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = np.zeros(n, bool)
    keep[1:] = areas >= min_share * areas.max()
    if ref is not None:
        overlap = np.bincount(lab[ref > 0], minlength=n)[1:]
        keep[1:] &= overlap > 0.2 * areas
        if not keep[1:].any() and overlap.any():
            keep[1 + int(np.argmax(overlap))] = True
    return keep[lab].astype(np.uint8)
