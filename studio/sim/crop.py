"""Bounding-box crop alignment of shadow images (DESIGN §4 "Losses"), differentiable in the pixel values.

Every image is compared on a crop: the bounding box of its shadow pixels (probability above a threshold), padded
by a few pixels, made square about its centre (so the aspect ratio is kept), and resampled to ``size × size``.
The box is found without gradient; the resampling (``grid_sample`` on an axis-aligned grid, supersampled and averaged
when it shrinks, so it does not alias) is differentiable in the pixel values. Boxes are in pixel-edge
coordinates: pixel ``(row i, col j)`` covers ``[j, j + 1] × [i, i + 1]``. Outside the image is lit backdrop (0).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

from studio.sim.crop_pad import PAD, pad_pixels


def as_image_batch(images: torch.Tensor | np.ndarray) -> torch.Tensor:
    """``(H, W)``, ``(B, H, W)`` or ``(B, 1, H, W)`` (tensor or array) → float ``(B, H, W)`` tensor."""
    x = torch.as_tensor(images)
    if not x.is_floating_point():
        x = x.float()
    if x.ndim == 4:
        if x.shape[1] != 1:
            raise ValueError(f"expected one channel in (B, 1, H, W), got shape {tuple(x.shape)}")
        x = x[:, 0]
    elif x.ndim == 2:
        x = x[None]
    if x.ndim != 3:
        raise ValueError(f"expected (H, W), (B, H, W) or (B, 1, H, W) images, got shape {tuple(x.shape)}")
    return x


@torch.no_grad()
def square_boxes(images: torch.Tensor, threshold: float = 0.5, pad: float = PAD) -> torch.Tensor:
    """Square crop boxes of shadow images ``(B, H, W)`` → ``(B, 4)`` float ``(x0, y0, x1, y1)`` pixel edges.

    The box holds the pixels above ``threshold``, grown by :func:`pad_pixels` on each side and then to a square
    about its centre. An image with no such pixel gets the whole image (made square).
    """
    B, H, W = images.shape
    x = images.detach()
    rows, cols = x.amax(dim=2) > threshold, x.amax(dim=1) > threshold  # (B, H), (B, W): any pixel above
    found = rows.any(dim=1)
    ar_h = torch.arange(H, device=images.device)
    ar_w = torch.arange(W, device=images.device)
    big = torch.tensor(10**9, device=images.device)
    y0 = torch.where(rows, ar_h, big).amin(dim=1)
    y1 = torch.where(rows, ar_h, -big).amax(dim=1) + 1
    x0 = torch.where(cols, ar_w, big).amin(dim=1)
    x1 = torch.where(cols, ar_w, -big).amax(dim=1) + 1
    y0 = torch.where(found, y0, torch.zeros_like(y0))
    y1 = torch.where(found, y1, torch.full_like(y1, H))
    x0 = torch.where(found, x0, torch.zeros_like(x0))
    x1 = torch.where(found, x1, torch.full_like(x1, W))
    p = torch.where(found, pad_pixels(pad, H, W), 0.0).to(images.dtype)
    cx, cy = (x0 + x1).to(images.dtype) / 2, (y0 + y1).to(images.dtype) / 2
    half = torch.maximum(x1 - x0, y1 - y0).to(images.dtype) / 2 + p
    return torch.stack([cx - half, cy - half, cx + half, cy + half], dim=1)


def crop_boxes(images: torch.Tensor, boxes: torch.Tensor, size: int) -> torch.Tensor:
    """Resample the ``boxes`` ``(B, 4)`` of ``images`` ``(B, H, W)`` to ``(B, size, size)``, differentiably.

    Bilinear ``grid_sample`` at ``k × size`` samples per side followed by ``k × k`` average pooling, with
    ``k = ceil(max(H, W) / size)``, approximates area averaging when the crop shrinks. ``k`` depends on the image
    size only, so a sample's crop does not depend on the rest of its batch.
    """
    B, H, W = images.shape
    boxes = boxes.to(images.dtype)
    k = max(1, math.ceil(max(H, W) / size))
    n = size * k
    u = (torch.arange(n, dtype=images.dtype, device=images.device) + 0.5) / n  # sample centres in (0, 1)
    x = boxes[:, 0:1] + (boxes[:, 2:3] - boxes[:, 0:1]) * u  # (B, n) pixel-edge coordinates
    y = boxes[:, 1:2] + (boxes[:, 3:4] - boxes[:, 1:2]) * u
    gx = (2 * x / W - 1)[:, None, :].expand(B, n, n)  # normalised, align_corners=False
    gy = (2 * y / H - 1)[:, :, None].expand(B, n, n)
    grid = torch.stack([gx, gy], dim=-1)  # (B, n, n, 2): an axis-aligned grid, no affine_grid matmul needed
    out = F.grid_sample(images[:, None], grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    if k > 1:
        out = F.avg_pool2d(out, k)
    return out[:, 0]


def align(
    images: torch.Tensor | np.ndarray, size: int = 256, pad: float = PAD, threshold: float = 0.5
) -> tuple[torch.Tensor, torch.Tensor]:
    """Crop-align shadow images: ``(B, [1,] H, W)`` → crops ``(B, size, size)`` and their boxes ``(B, 4)``."""
    x = as_image_batch(images)
    boxes = square_boxes(x, threshold, pad)
    return crop_boxes(x, boxes, size), boxes
