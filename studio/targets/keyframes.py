"""Keyframes of a sequence: cluster its frames by their expressive masks, one pose per cluster (DESIGN §4).

Expressive masks ``(N, S, S)`` → area resize to ``size × size`` → flatten → PCA (``components``, at most N and
the pixel count) → embeddings ``E (N, C)``. Distances are L2 in that space divided by the largest distance between
two frames, so 0 = identical and 1 = the two most different frames of the sequence. Clustering starts with one
cluster per frame and repeatedly merges the two closest clusters (a cluster's embedding is the mean of its members'
embeddings) while their similarity ``1 − d`` is at least ``tau``. The first pair that is not similar enough ends
the merging, so the merge order does not depend on ``tau`` and a higher ``tau`` never gives fewer clusters. A
cluster's representative (its keyframe) is the member nearest the cluster's mean; keyframes are numbered in order
of first appearance, and every frame plays its cluster's keyframe pose.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import cv2
import numpy as np

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class KeyframeConfig:
    """How frames are grouped into keyframes (paper: PCA 50 of 64 × 64 expressive masks; τ chosen here)."""

    # tau: measured on the six shared DAVIS mask sequences (shared/targets/davis, 24 fps) loaded by load_video at
    # its defaults (4 Hz, one square frame of 128 px); frames → keyframes (reduction) [paper's frames → keyframes]:
    #   bear 14 → 2 (86 %) [60 → 5], blackswan 9 → 3 (67 %) [16 → 5], camel 15 → 2 (87 %) [39 → 6],
    #   cows 18 → 2 (89 %) [12 → 3], dog 10 → 2 (80 %) [21 → 6], flamingo 14 → 4 (71 %) [27 → 10];
    #   all 80 → 15 (81 %; paper 175 → 35, 80 %). Every tau in [0.385, 0.40] keeps all six in the paper's 63–92 %
    #   (0.39 is its middle); at 0.34 bear and cows collapse to one keyframe, at 0.405 flamingo keeps 6 of 14
    #   (57 %), at 0.48 blackswan 6 of 9 (33 %). At 5 Hz tau 0.39 gives 73–95 %, at 3 Hz 30–85 %.
    tau: float = 0.39  # similarity 1 − d at which the two closest clusters still merge; higher = more keyframes [0, 1]
    size: int = 64  # side of the square the expressive masks are area-resized to before PCA, px [1, ∞)
    components: int = 50  # PCA components kept (at most the frame count and size²) [1, ∞)

    def __post_init__(self) -> None:
        if not 0 <= self.tau <= 1:
            raise ValueError(f"tau must be a similarity in [0, 1], not {self.tau}")
        if self.size < 1 or self.components < 1:
            raise ValueError("size and components must be at least 1")


@dataclass
class Clusters:
    """Frames grouped into keyframes, numbered in order of first appearance.

    ``assignment (N,)`` int: keyframe number of each frame; ``representatives (K,)`` int: frame index of each
    keyframe; ``members``: K ascending lists of frame indices (``members[k][0]`` is keyframe k's first frame).
    """

    assignment: np.ndarray
    representatives: np.ndarray
    members: list[list[int]]

    @property
    def count(self) -> int:
        """Number of keyframes K."""
        return len(self.members)

    @property
    def reduction(self) -> float:
        """Share of frames that need no optimisation of their own: 1 − K / N."""
        return 1.0 - self.count / len(self.assignment)


def embed(expressive: np.ndarray, cfg: KeyframeConfig = KeyframeConfig()) -> np.ndarray:
    """Expressive masks ``(N, S, S)`` → PCA embeddings ``(N, C)`` float64, C = min(components, N, size²) (1 when
    every frame is alike)."""
    from sklearn.decomposition import PCA

    masks = np.asarray(expressive)
    if masks.ndim != 3 or masks.shape[0] == 0:
        raise ValueError(f"expressive masks must be (N, S, S) with N ≥ 1, not an array of shape {masks.shape}")
    small = np.stack([
        cv2.resize((m != 0).astype(np.float32), (cfg.size, cfg.size), interpolation=cv2.INTER_AREA) for m in masks
    ]).reshape(len(masks), -1)  # fmt: skip
    small = small.astype(np.float64)
    unique, inverse = np.unique(small, axis=0, return_inverse=True)
    if len(unique) == 1:  # every frame alike: no variance to project, every distance is 0
        return np.zeros((len(small), 1))
    pca = PCA(n_components=min(cfg.components, *small.shape), svd_solver="full").fit(small)
    return pca.transform(unique)[inverse.ravel()]  # identical frames get bit-identical embeddings (d = 0 exactly)


def merge_clusters(embeddings: np.ndarray, tau: float) -> list[list[int]]:
    """Centroid merging of ``embeddings (N, C)`` until the closest pair's similarity ``1 − d`` falls below ``tau``.

    ``d`` is the L2 distance between the clusters' mean embeddings over the largest distance between two frames.
    Returns the clusters as ascending member lists, ordered by first member. O(N²·C) time: after a merge only the
    merged cluster's row of the distance matrix is recomputed.
    """
    e = np.asarray(embeddings, np.float64)
    n = len(e)
    diff = e[:, None, :] - e[None, :, :]
    dist = np.sqrt(np.einsum("ijk,ijk->ij", diff, diff))
    scale = dist.max()
    scale = scale if scale > 0 else 1.0  # all frames identical: every distance is 0, everything merges
    d = dist / scale
    np.fill_diagonal(d, np.inf)
    centroids = e.copy()
    sizes = np.ones(n)
    members: list[list[int]] = [[i] for i in range(n)]
    alive = np.ones(n, bool)
    for _ in range(n - 1):
        flat = int(np.argmin(d))  # row-major: ties go to the lowest pair, so the merge order is reproducible
        i, j = divmod(flat, n)
        if not np.isfinite(d[i, j]) or 1.0 - d[i, j] < tau:
            break
        i, j = min(i, j), max(i, j)
        centroids[i] = (sizes[i] * centroids[i] + sizes[j] * centroids[j]) / (sizes[i] + sizes[j])
        sizes[i] += sizes[j]
        members[i] = sorted(members[i] + members[j])
        alive[j] = False
        d[j, :] = d[:, j] = np.inf
        row = np.linalg.norm(centroids - centroids[i], axis=1) / scale
        row[~alive] = np.inf
        row[i] = np.inf
        d[i, :] = d[:, i] = row
    return sorted((members[i] for i in np.flatnonzero(alive)), key=lambda m: m[0])


def cluster_keyframes(expressive: np.ndarray, cfg: KeyframeConfig = KeyframeConfig()) -> Clusters:
    """Expressive masks ``(N, S, S)`` → :class:`Clusters` (module doc): keyframes in order of first appearance."""
    e = embed(expressive, cfg)
    members = merge_clusters(e, cfg.tau)
    assignment = np.empty(len(e), np.int64)
    reps = np.empty(len(members), np.int64)
    for k, group in enumerate(members):
        assignment[group] = k
        centre = e[group].mean(axis=0)
        reps[k] = group[int(np.argmin(np.linalg.norm(e[group] - centre, axis=1)))]
    log.debug("%d frames → %d keyframes (tau %.3f)", len(e), len(members), cfg.tau)
    return Clusters(assignment=assignment, representatives=reps, members=members)


def keyframe_targets(
    masks: np.ndarray, expressive: np.ndarray | None, representatives: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """Frames ``(N, S, S)`` (and their expressive masks) → the keyframes' ``(K, S, S)`` in first-appearance order,
    ``representatives (K,)`` being :attr:`Clusters.representatives`."""
    reps = np.asarray(representatives, dtype=np.int64)
    return np.asarray(masks)[reps], (None if expressive is None else np.asarray(expressive)[reps])
