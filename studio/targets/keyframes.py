"""Keyframes of a sequence: cluster its frames by their expressive masks' *shape*, one pose per cluster (DESIGN §4).

The robot hand can change the shadow's shape but never move it across the backdrop, and the losses compare every
image on its own aligned crop; so frames are compared the same way, each in its own crop, and a subject that walks
or flies across the frame is not grouped by where it is. Clustering is invariant to shifting the frames and, up to
resampling, to scaling them.

Each expressive mask ``(S, S)`` → :func:`aligned_crop`: a box padded by the losses' ``LossConfig.pad`` pixels of a
256-pixel image (scaled to ``S``), squared about its centre, area-resampled to ``size × size``; an empty mask gives
an empty crop. The box is the frame's shadow's when the shadows are given, as the losses crop the expressive region
with the target's box (an arm raised or lowered against a still body is then another shape), else the expressive
mask's own; the two agree where the whole subject moves, as in DAVIS. → Gaussian blur of σ = ``blur × size`` (a
small misalignment of thin parts, legs and tails, counts a little, not as another shape) → flatten → PCA
(``components``, at most N and the pixel count) → embeddings ``E (N, C)``. Distances are L2 in that space divided by
the largest distance between two frames, so 0 = identical and 1 = the two most different frames of the sequence.
Clustering starts with one cluster per frame and repeatedly merges the two closest clusters (a cluster's embedding
is the mean of its members' embeddings) while their similarity ``1 − d`` is at least ``tau``. The first pair that is
not similar enough ends the merging, so the merge order does not depend on ``tau`` and a higher ``tau`` never gives
fewer clusters. A cluster's representative (its keyframe) is the member nearest the cluster's mean; keyframes are
numbered in order of first appearance, and every frame plays its cluster's keyframe pose. The merging, on the
embeddings alone, is :mod:`studio.targets.merging`.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from studio.sim.crop_pad import PAD, pad_pixels
from studio.targets.merging import Clusters, MergeOrder, merge_clusters


@dataclass(frozen=True)
class KeyframeConfig:
    """How frames are grouped into keyframes (paper: PCA 50 of 64 × 64 expressive masks; τ chosen here)."""

    # tau: measured on the six shared DAVIS mask sequences (shared/targets/davis, 24 fps) loaded by load_video at
    # its defaults (4 Hz, one square frame of 128 px), expressive masks by expressive_masks, each in its own aligned
    # crop (its own box or its frame's shadow box: the same counts); frames → keyframes (reduction) [paper's]:
    #   bear 14 → 2 (86 %) [60 → 5], blackswan 9 → 2 (78 %) [16 → 5], camel 15 → 2 (87 %) [39 → 6],
    #   cows 18 → 2 (89 %) [12 → 3], dog 10 → 3 (70 %) [21 → 6], flamingo 14 → 2 (86 %) [27 → 10];
    #   all 80 → 13 (84 %; paper 175 → 35, 80 %). Every tau up to 0.422 keeps all six in the paper's 63–92 % (each
    #   keeps at least two keyframes at any tau, one_iou below; under 0.36 dog drops to 2 of 10, 80 %); at 0.424 dog
    #   keeps 4 of 10 (60 %). At 3 Hz tau 0.404 gives 62–85 % (dog 8 → 3), at 5 Hz 82–91 %. Measured with frames
    #   that keep the masks' holes (studio.targets.holes); 0.404 was chosen as the middle of [0.389, 0.419], the
    #   interval when framing closed thin gaps into holes (flamingo then 14 → 3) and before one_iou. Without the
    #   blur no tau kept all six at 4 Hz then (camel needed ≥ 0.333, dog ≤ 0.312), nor with σ ≤ 3 px of 64; blur
    #   0.11 (σ 7 px) was the least blur whose interval was 0.03 wide (σ 6 px: 0.017, σ 10 px: 0.067, coarser).
    tau: float = 0.404  # similarity 1 − d at which the two closest clusters still merge; higher = more keyframes [0, 1]
    size: int = 64  # side of the square each expressive mask's aligned crop is area-resized to before PCA, px [1, 512]
    blur: float = 0.11  # σ of the Gaussian blur of each crop before PCA, fraction of its side (0: none) [0, 10]
    components: int = 50  # PCA components kept (at most the frame count and size²) [1, 1000]
    one_iou: float = 0.9  # frames whose crops overlap less than this (IoU) are never all one keyframe [0, 1]

    def __post_init__(self) -> None:
        if not 0 <= self.tau <= 1:
            raise ValueError(f"tau must be a similarity in [0, 1], not {self.tau}")
        if self.size < 1 or self.components < 1:
            raise ValueError("size and components must be at least 1")
        if not 0 <= self.one_iou <= 1:
            raise ValueError(f"one_iou must be an IoU in [0, 1], not {self.one_iou}")
        if not self.blur >= 0:
            raise ValueError(f"blur must be a fraction of the crop side ≥ 0, not {self.blur}")


def aligned_crop(mask: np.ndarray, size: int, pad: float = PAD, box_of: np.ndarray | None = None) -> np.ndarray:
    """Mask ``(H, W)`` → its aligned crop ``(size, size)`` float64 in [0, 1], as the losses crop (DESIGN §4).

    The box of the nonzero pixels of ``box_of`` (same shape; None or empty: of ``mask`` itself), in pixel edges,
    grown by ``pad`` pixels of a 256-pixel image scaled with the longer side, then to a square about its centre
    (aspect ratio kept), is area-averaged exactly to ``size × size`` (outside the image is backdrop, 0). A mask with
    no pixel gives an empty crop (all zeros).
    """
    m = np.asarray(mask) != 0
    if not m.any():
        return np.zeros((size, size))
    b = m if box_of is None or not np.any(box_of) else np.asarray(box_of) != 0
    if b.shape != m.shape:
        raise ValueError(f"the box's mask has shape {b.shape}, not the mask's {m.shape}")
    rows, cols = np.flatnonzero(b.any(axis=1)), np.flatnonzero(b.any(axis=0))
    p = pad_pixels(pad, *m.shape)
    half = max(rows[-1] + 1 - rows[0], cols[-1] + 1 - cols[0]) / 2 + p
    cy, cx = (rows[0] + rows[-1] + 1) / 2, (cols[0] + cols[-1] + 1) / 2

    def weights(centre: float, n: int) -> np.ndarray:  # (size, n): share of each output cell covered by pixel j
        edges = centre - half + 2 * half * np.arange(size + 1) / size
        j = np.arange(n)
        overlap = np.minimum(edges[1:, None], j + 1) - np.maximum(edges[:-1, None], j)
        return np.clip(overlap, 0, None) / (2 * half / size)

    return weights(cy, m.shape[0]) @ m.astype(np.float64) @ weights(cx, m.shape[1]).T


def _crops(masks: np.ndarray, cfg: KeyframeConfig, shadows: np.ndarray | None) -> list[np.ndarray]:
    """Each of ``masks (N, S, S)`` cut to its :func:`aligned_crop` (``(size, size)`` float64), boxed by its shadow."""
    masks = np.asarray(masks)
    if masks.ndim != 3 or masks.shape[0] == 0:
        raise ValueError(f"expressive masks must be (N, S, S) with N ≥ 1, not an array of shape {masks.shape}")
    if shadows is not None and np.shape(shadows) != masks.shape:
        raise ValueError(f"shadows must have the expressive masks' shape {masks.shape}, not {np.shape(shadows)}")
    boxes = [None] * len(masks) if shadows is None else list(np.asarray(shadows))
    return [aligned_crop(m, cfg.size, box_of=b) for m, b in zip(masks, boxes, strict=True)]


def most_different_iou(
    expressive: np.ndarray, cfg: KeyframeConfig, shadows: np.ndarray | None = None, below: float = 0.0
) -> float:
    """The soft IoU (Σ min / Σ max) of the aligned crops of the two frames least alike, 1 when all are alike: how
    much the subject's shape changes through the clip, in the crops' own terms (not relative to the clip). One frame
    against the later ones at a time: memory O(N·size²), not the (N, N, size²) of every pair at once (1.9 GB for
    240 frames). With ``below`` > 0 it stops at the first pair whose IoU is under ``below`` and returns that IoU
    (enough to know the shape changes)."""
    return _least_alike(_crops(expressive, cfg, shadows), below)


def _least_alike(crops: list[np.ndarray], below: float) -> float:
    c = np.stack(crops).reshape(len(crops), -1)
    worst = 1.0
    for i in range(len(c) - 1):
        lo = np.minimum(c[i], c[i + 1 :]).sum(axis=-1)
        hi = np.maximum(c[i], c[i + 1 :]).sum(axis=-1)
        worst = min(worst, float(np.where(hi > 0, lo / np.maximum(hi, 1e-12), 1.0).min()))
        if worst < below:
            break
    return worst


def embed(
    expressive: np.ndarray, cfg: KeyframeConfig = KeyframeConfig(), shadows: np.ndarray | None = None
) -> np.ndarray:
    """Expressive masks ``(N, S, S)`` → PCA embeddings ``(N, C)`` float64, C = min(components, N, size²) (1 when
    every frame is alike). Each mask is first cut to its :func:`aligned_crop` of side ``cfg.size``: the box of its
    frame's shadow in ``shadows (N, S, S)``, as the losses crop the expressive region with the target's box (the
    expressive part is then seen where it is on the shadow: an arm raised or lowered), or with None its own box."""
    return _embed(_crops(expressive, cfg, shadows), cfg)


def _embed(crops: list[np.ndarray], cfg: KeyframeConfig) -> np.ndarray:
    if cfg.blur > 0:  # outside the crop is backdrop (0), as in the crop itself
        crops = [cv2.GaussianBlur(c, (0, 0), cfg.blur * cfg.size, borderType=cv2.BORDER_CONSTANT) for c in crops]
    small = np.round(np.stack(crops).reshape(len(crops), -1), 9)  # shifted copies: bit-identical crops
    unique, inverse = np.unique(small, axis=0, return_inverse=True)
    if len(unique) == 1:  # every frame alike: no variance to project, every distance is 0
        return np.zeros((len(small), 1))
    e = pca(small, unique, min(cfg.components, *small.shape))
    return e[inverse.ravel()]  # identical frames get bit-identical embeddings (d = 0 exactly)


def pca(x: np.ndarray, y: np.ndarray, n: int) -> np.ndarray:
    """Rows ``y (M, F)`` projected on the first ``n`` principal components of ``x (N, F)`` float64 → ``(M, n)``: the
    full SVD of the centred ``x``, each component's sign set so that its largest entry is positive. The arithmetic is
    scikit-learn's ``PCA(n, svd_solver="full").fit(x).transform(y)`` (1.9, read to match it), bit for bit (a test
    holds them equal), without its 1.2 s import."""
    import scipy.linalg  # here: a still (one frame) has nothing to project

    mean = np.mean(x, axis=0)
    _, _, vt = scipy.linalg.svd(x - mean, full_matrices=False)
    vt *= np.sign(vt[np.arange(len(vt)), np.argmax(np.abs(vt), axis=1)])[:, None]
    components = vt[:n]
    return y @ components.T - mean.reshape(1, -1) @ components.T


def cluster_keyframes(
    expressive: np.ndarray, cfg: KeyframeConfig = KeyframeConfig(), shadows: np.ndarray | None = None
) -> Clusters:
    """Expressive masks ``(N, S, S)`` → :class:`Clusters` (module doc): keyframes in order of first appearance.
    ``shadows (N, S, S)``: the frames' shadow masks, whose boxes crop the expressive masks (:func:`embed`). A clip
    whose two least alike frames' crops overlap less than ``cfg.one_iou`` keeps at least two keyframes, whatever
    ``tau`` (merging is relative to the clip's own largest change, so a steady change could otherwise merge whole).
    The clusters at another τ of the same frames: ``merge_order(...).clusters(tau)``, without merging again."""
    return merge_order(expressive, cfg, shadows).clusters(cfg.tau)


def merge_order(
    expressive: np.ndarray, cfg: KeyframeConfig = KeyframeConfig(), shadows: np.ndarray | None = None
) -> MergeOrder:
    """The :class:`MergeOrder` of expressive masks ``(N, S, S)`` (``cfg.tau`` is not used; ``shadows`` as in
    :func:`cluster_keyframes`)."""
    crops = _crops(expressive, cfg, shadows)  # cut once: the embedding and the change of shape both read them
    e = _embed(crops, cfg)
    distances: list[float] = []
    pairs: list[tuple[int, int]] = []
    merge_clusters(e, -np.inf, distances=distances, pairs=pairs)
    changes = len(distances) > 0 and _least_alike(crops, cfg.one_iou) < cfg.one_iou
    return MergeOrder(np.array(distances, np.float64), np.array(pairs, np.int64).reshape(-1, 2), e, bool(changes))


def keyframe_targets(
    masks: np.ndarray, expressive: np.ndarray | None, representatives: np.ndarray
) -> tuple[np.ndarray, np.ndarray | None]:
    """Frames ``(N, S, S)`` (and their expressive masks) → the keyframes' ``(K, S, S)`` in first-appearance order,
    ``representatives (K,)`` being :attr:`Clusters.representatives`."""
    reps = np.asarray(representatives, dtype=np.int64)
    return np.asarray(masks)[reps], (None if expressive is None else np.asarray(expressive)[reps])
