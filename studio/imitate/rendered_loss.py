"""The image loss of *rendered* (binary) shadows, compiled: the fast path of :class:`~studio.imitate.losses.ImageLoss`.

Refinement and retrieval score thousands of uint8 shadows per second against one target. ``ImageLoss`` does that in
torch (box, ``grid_sample`` crop, MAE, soft IoU) at ≈ 0.2 ms a shadow on one core; the kernels here do the same
arithmetic in numba at a fraction of it. The crop of :func:`studio.sim.crop.crop_boxes` is an axis-aligned bilinear
resampling followed by ``k × k`` average pooling, so it is separable: rows are resampled first (``(size, W)``), then
columns. Everything is float32 like the reference; results agree with ``ImageLoss`` to ~1e-6
(``tests/test_rendered_loss.py``). CLIP and several targets stay on the torch path (:func:`fast_loss` returns None).
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit, prange

from studio.imitate.losses import ImageLoss
from studio.sim.crop_pad import pad_pixels
from studio.sim.raster import serial_twin


@njit(cache=True)
def _square_box(img, pad):
    """The box of :func:`studio.sim.crop.square_boxes` for one binary image ``(H, W)`` → (x0, y0, x1, y1)."""
    H, W = img.shape
    y0, y1, x0, x1 = H, -1, W, -1
    for i in range(H):
        for j in range(W):
            if img[i, j] != 0:
                if i < y0:
                    y0 = i
                y1 = i
                if j < x0:
                    x0 = j
                if j > x1:
                    x1 = j
    if y1 < 0:  # empty: the whole image, no pad
        cx, cy, half = W / 2.0, H / 2.0, max(W, H) / 2.0
    else:
        cx, cy = (x0 + x1 + 1) / 2.0, (y0 + y1 + 1) / 2.0
        half = max(x1 + 1 - x0, y1 + 1 - y0) / 2.0 + pad
    return cx - half, cy - half, cx + half, cy + half


@njit(cache=True)
def _axis_taps(lo, hi, size, k, extent, idx, wgt):
    """Bilinear taps of the ``size·k`` sample centres of ``[lo, hi]`` on an axis of ``extent`` pixels (zeros outside):
    ``idx[s]`` the lower pixel, ``wgt[s]`` the weight of the upper one (grid_sample, align_corners=False)."""
    n = size * k
    for s in range(n):
        u = np.float32((s + 0.5) / n)
        x = np.float32(lo) + (np.float32(hi) - np.float32(lo)) * u
        g = np.float32(2.0) * x / np.float32(extent) - np.float32(1.0)
        ix = ((g + np.float32(1.0)) * np.float32(extent) - np.float32(1.0)) / np.float32(2.0)
        f = math.floor(ix)
        idx[s] = int(f)
        wgt[s] = ix - f


@njit(cache=True)
def _crop_one(img, pad, size, k, out, tmp, iy, wy, ix, wx):
    """Aligned crop of one binary image ``(H, W)`` into ``out (size, size)`` float32 (``crop_boxes`` of its box)."""
    H, W = img.shape
    x0, y0, x1, y1 = _square_box(img, pad)
    _axis_taps(y0, y1, size, k, H, iy, wy)
    _axis_taps(x0, x1, size, k, W, ix, wx)
    inv = np.float32(1.0 / k)
    for r in range(size):  # rows: (size, W), pooled over k samples
        for j in range(W):
            tmp[r, j] = 0.0
        for q in range(k):
            s = r * k + q
            a, w = iy[s], wy[s]
            if 0 <= a < H:
                for j in range(W):
                    tmp[r, j] += (np.float32(1.0) - w) * img[a, j]
            if 0 <= a + 1 < H:
                for j in range(W):
                    tmp[r, j] += w * img[a + 1, j]
    for r in range(size):  # columns: (size, size)
        for c in range(size):
            acc = np.float32(0.0)
            for q in range(k):
                s = c * k + q
                a, w = ix[s], wx[s]
                v = np.float32(0.0)
                if 0 <= a < W:
                    v += (np.float32(1.0) - w) * tmp[r, a]
                if 0 <= a + 1 < W:
                    v += w * tmp[r, a + 1]
                acc += v
            out[r, c] = acc * inv * inv if k > 1 else acc


@njit(cache=True, parallel=True, nogil=True)
def crop_batch(shadows, pad, size):
    """Aligned crops of binary shadows ``(B, H, W)`` uint8 → ``(B, size, size)`` float32 (``studio.sim.crop.align``)."""
    B, H, W = shadows.shape
    k = max(1, -(-max(H, W) // size))
    out = np.empty((B, size, size), dtype=np.float32)
    for b in prange(B):
        n = size * k
        tmp = np.empty((size, W), dtype=np.float32)
        iy, ix = np.empty(n, np.int64), np.empty(n, np.int64)
        wy, wx = np.empty(n, np.float32), np.empty(n, np.float32)
        _crop_one(shadows[b], pad, size, k, out[b], tmp, iy, wy, ix, wx)
    return out


@njit(cache=True, inline="always")
def _score_one(crop, target, mask, has_mask, eps, out):
    """One aligned crop ``(size, size)`` against the target → ``out (3,)``: mae, iou_loss, exp_iou."""
    size = target.shape[0]
    sad, inter, union, m_inter, m_union = 0.0, 0.0, 0.0, 0.0, 0.0
    for i in range(size):
        for j in range(size):
            p, t = crop[i, j], target[i, j]
            sad += abs(p - t)
            inter += min(p, t)
            union += max(p, t)
            if has_mask:
                mp, mt = mask[i, j] * p, mask[i, j] * t
                m_inter += min(mp, mt)
                m_union += max(mp, mt)
    out[0] = sad / (size * size)
    out[1] = 1.0 - (inter + eps) / (union + eps)
    out[2] = 1.0 - (m_inter + eps) / (m_union + eps) if has_mask else np.nan


CHUNK = 16  # shadows per scratch allocation (the threaded kernel's unit of work)


def _scores(shadows, target, mask, has_mask, pad, eps):
    """Binary shadows ``(B, H, W)`` uint8 against one aligned target crop ``(size, size)`` → ``(B, 3)`` float32."""
    B, H, W = shadows.shape
    size = target.shape[0]
    k = max(1, -(-max(H, W) // size))
    n = size * k
    out = np.empty((B, 3), dtype=np.float32)  # mae, iou_loss, exp_iou
    for c in prange((B + CHUNK - 1) // CHUNK):
        crop = np.empty((size, size), dtype=np.float32)
        tmp = np.empty((size, W), dtype=np.float32)
        iy, ix = np.empty(n, np.int64), np.empty(n, np.int64)
        wy, wx = np.empty(n, np.float32), np.empty(n, np.float32)
        for b in range(c * CHUNK, min(B, (c + 1) * CHUNK)):
            _crop_one(shadows[b], pad, size, k, crop, tmp, iy, wy, ix, wx)
            _score_one(crop, target, mask, has_mask, eps, out[b])
    return out


# Two compilations of one kernel: serial for the small batches of refinement, threads over the batch for large ones
# (each under its own name, so neither loads the other's compiled code from numba's disk cache: serial_twin).
_scores_parallel = njit(cache=True, parallel=True, nogil=True)(_scores)  # nogil: UI threads run
_scores_serial = njit(cache=True, nogil=True)(serial_twin(_scores))
PARALLEL_FROM = 256  # batches at least this large use the threaded kernel


class RenderedLoss:
    """``ImageLoss`` (no CLIP, one target) for binary shadows ``(B, H, W)`` uint8, returning numpy.

    ``loss(shadows, theta=None, theta_prev=None) -> (total (B,), {component: (B,)})`` with the components of
    :data:`studio.imitate.config.COMPONENTS` (NaN = not computed), as float64 arrays.
    """

    def __init__(self, loss_fn: ImageLoss):
        if loss_fn.clip is not None or loss_fn.n_targets != 1:
            raise ValueError("the compiled loss handles one target without CLIP; use ImageLoss")
        self.cfg = loss_fn.cfg
        self.target = np.ascontiguousarray(loss_fn.target_crop[0].detach().cpu().numpy(), dtype=np.float32)
        self.has_mask = loss_fn.mask_crop is not None
        m = loss_fn.mask_crop[0] if self.has_mask else torch.zeros(1, 1)
        self.mask = np.ascontiguousarray(m.detach().cpu().numpy(), dtype=np.float32)

    def pad(self, height: int, width: int) -> float:
        return pad_pixels(self.cfg.pad, height, width)

    def __call__(
        self, shadows: np.ndarray, theta: np.ndarray | None = None, theta_prev: np.ndarray | None = None
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        s = np.ascontiguousarray(shadows, dtype=np.uint8)
        if s.ndim == 2:
            s = s[None]
        kernel = _scores_parallel if len(s) >= PARALLEL_FROM else _scores_serial
        raw = kernel(s, self.target, self.mask, self.has_mask, self.pad(*s.shape[1:]), self.cfg.eps).astype(np.float64)
        cfg, nan = self.cfg, np.full(len(s), np.nan)
        c = {"mae": raw[:, 0], "iou_loss": raw[:, 1], "clip": nan}
        c["base"] = cfg.w_mae * c["mae"] + cfg.w_iou * c["iou_loss"]
        total = c["base"]
        if self.has_mask:
            c["exp_iou"], c["exp_clip"] = raw[:, 2], nan
            c["expr"] = cfg.w_exp_iou * c["exp_iou"]
            total = total + c["expr"]
        else:
            c["exp_iou"] = c["exp_clip"] = c["expr"] = nan
        if theta is not None and theta_prev is not None:
            d = np.atleast_2d(np.asarray(theta, np.float64)) - np.asarray(theta_prev, np.float64)
            c["temporal"] = cfg.w_temporal * (d**2).sum(axis=-1)
            total = total + c["temporal"]
        else:
            c["temporal"] = nan
        c["total"] = total
        return total, c


def fast_loss(loss_fn: ImageLoss) -> RenderedLoss | None:
    """The compiled twin of ``loss_fn`` when it has one (no CLIP, one target), else None (use ``loss_fn``)."""
    if loss_fn.clip is not None or loss_fn.n_targets != 1:
        return None
    return RenderedLoss(loss_fn)
