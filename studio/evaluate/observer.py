"""An independent observer: does a shadow read as its target's class?

The observer names the class of a silhouette by its nearest neighbours in a gallery of other silhouettes of known
classes (other images than the ones imitated: another signer's hands, other MPEG-7 instances). It looks at the
shapes through descriptors the studio's losses never use, so it is a second opinion rather than the objective
again:

* ``"hog"``: histograms of gradient orientations (Dalal & Triggs' HOG) of the silhouette's square bounding-box
  crop, resized to ``side`` pixels; position and size do not matter, orientation does (a sideways ``h`` is not a ``u``);
* ``"fourier"``: the magnitudes of the Fourier series of the outline's distance from its centroid (the largest
  outline, resampled by arc length), divided by the mean distance; position, size, rotation and the outline's
  starting point do not matter (the classic MPEG-7 shape descriptor).

The measure of a set of targets is how often the observer names the target's class for the target itself and for
the shadow imitating it; a shadow that reads as its target is named as often as the target is.

Pure compute on masks ``(H, W)`` uint8 (1 = silhouette); :mod:`benchmarks.bench_observer` runs it on held-out
images and the studio's shadows of them.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

__all__ = ["DESCRIPTORS", "Observer", "ObserverConfig", "describe"]

DESCRIPTORS = ("hog", "fourier")


@dataclass(frozen=True)
class ObserverConfig:
    """How the observer looks at silhouettes."""

    descriptor: str = "hog"  # "hog" (orientation kept) or "fourier" (rotation-invariant outline)
    k: int = 1  # neighbours that vote (ties: the nearest of the tied classes) [1, 100]
    side: int = 64  # HOG: the square crop's side, pixels (a multiple of 8) [16, 512]
    harmonics: int = 24  # Fourier: magnitudes kept after the constant term [4, 64]
    points: int = 256  # Fourier: outline points after resampling by arc length [32, 4096]

    def __post_init__(self) -> None:
        if self.descriptor not in DESCRIPTORS:
            raise ValueError(f"descriptor must be one of {DESCRIPTORS}, got {self.descriptor!r}")
        if self.k < 1 or self.side < 16 or self.side % 8 or not 4 <= self.harmonics < self.points // 2:
            raise ValueError(f"observer needs k ≥ 1, side a multiple of 8 ≥ 16 and 4 ≤ harmonics < points/2: {self}")


def _square_crop(mask: np.ndarray, side: int) -> np.ndarray:
    """The silhouette's bounding box padded to a square (centred), resized to ``side``² float32 in [0, 1]."""
    ys, xs = np.nonzero(mask)
    if not len(ys):
        return np.zeros((side, side), np.float32)
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    n = max(y1 - y0, x1 - x0) + 2
    box = np.zeros((n, n), np.float32)
    oy, ox = (n - (y1 - y0)) // 2, (n - (x1 - x0)) // 2
    box[oy : oy + y1 - y0, ox : ox + x1 - x0] = mask[y0:y1, x0:x1] > 0
    return cv2.resize(box, (side, side), interpolation=cv2.INTER_AREA)


def _hog(mask: np.ndarray, cfg: ObserverConfig) -> np.ndarray:
    """Histograms of oriented gradients (Dalal & Triggs): 9 unsigned orientation bins per 8×8-pixel cell, each
    2×2-cell block L2-normalised, blocks overlapping by one cell."""
    img = cv2.GaussianBlur(_square_crop(mask, cfg.side), (0, 0), 1.0)
    gy, gx = np.gradient(img.astype(np.float64))
    mag, ang = np.hypot(gx, gy), np.mod(np.arctan2(gy, gx), np.pi)
    cell, bins = 8, 9
    n = cfg.side // cell
    b = np.minimum((ang / np.pi * bins).astype(int), bins - 1)
    hist = np.zeros((n, n, bins))
    rows, cols = np.indices(img.shape)
    np.add.at(hist, (rows // cell, cols // cell, b), mag)
    blocks = np.stack([hist[i : i + 2, j : j + 2].ravel() for i in range(n - 1) for j in range(n - 1)])
    blocks /= np.linalg.norm(blocks, axis=1, keepdims=True) + 1e-6
    v = blocks.ravel()
    return v / (np.linalg.norm(v) + 1e-12)


def _fourier(mask: np.ndarray, cfg: ObserverConfig) -> np.ndarray:
    contours, _ = cv2.findContours((mask > 0).astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return np.zeros(cfg.harmonics)
    c = max(contours, key=cv2.contourArea)[:, 0, :].astype(np.float64)
    c = np.vstack([c, c[:1]])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(c, axis=0), axis=1))])
    if arc[-1] <= 0:
        return np.zeros(cfg.harmonics)
    t = np.linspace(0.0, arc[-1], cfg.points, endpoint=False)
    pts = np.stack([np.interp(t, arc, c[:, 0]), np.interp(t, arc, c[:, 1])], axis=1)
    r = np.linalg.norm(pts - pts.mean(axis=0), axis=1)
    f = np.abs(np.fft.rfft(r))
    return f[1 : cfg.harmonics + 1] / (f[0] + 1e-12)


def describe(mask: np.ndarray, cfg: ObserverConfig | None = None) -> np.ndarray:
    """The descriptor ``(D,)`` of one silhouette ``(H, W)`` (module doc)."""
    cfg = cfg or ObserverConfig()
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"a silhouette is (H, W), not shape {mask.shape}")
    return _hog(mask, cfg) if cfg.descriptor == "hog" else _fourier(mask, cfg)


class Observer:
    """Names a silhouette's class by its ``k`` nearest gallery silhouettes (module doc)."""

    def __init__(self, labels: Sequence[str], masks: Sequence[np.ndarray], cfg: ObserverConfig | None = None):
        if len(labels) != len(masks) or not len(labels):
            raise ValueError(f"a gallery needs one label per mask, and at least one: {len(labels)} vs {len(masks)}")
        self.cfg = cfg or ObserverConfig()
        self.labels = list(labels)
        self.gallery = np.stack([describe(m, self.cfg) for m in masks])

    @property
    def classes(self) -> list[str]:
        return sorted(set(self.labels))

    def name(self, mask: np.ndarray) -> str:
        """The class the observer sees in ``mask``."""
        d = np.linalg.norm(self.gallery - describe(mask, self.cfg), axis=1)
        near = np.argsort(d, kind="stable")[: self.cfg.k]
        votes = Counter(self.labels[i] for i in near)
        top = max(votes.values())
        return next(self.labels[i] for i in near if votes[self.labels[i]] == top)  # ties: the nearest
