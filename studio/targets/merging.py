"""The merging behind keyframes (:mod:`studio.targets.keyframes`), on embeddings alone: centroid merging of the two
closest clusters while they are similar enough (:func:`merge_clusters`), and the record of every merge it makes,
whose order does not depend on τ (:class:`MergeOrder`: the clusters and their count at any τ without merging again).
Distances are L2 between the clusters' mean embeddings over the largest distance between two frames; a cluster's
representative is the member nearest its mean."""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

log = logging.getLogger(__name__)


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


def merge_clusters(
    embeddings: np.ndarray,
    tau: float,
    keep: int = 1,
    distances: list[float] | None = None,
    pairs: list[tuple[int, int]] | None = None,
) -> list[list[int]]:
    """Centroid merging of ``embeddings (N, C)`` until the closest pair's similarity ``1 − d`` falls below ``tau``
    (or only ``keep`` clusters are left).

    ``d`` is the L2 distance between the clusters' mean embeddings over the largest distance between two frames.
    Returns the clusters as ascending member lists, ordered by first member; ``distances`` and ``pairs``, when given,
    get the ``d`` of each merge made and the clusters it merged ``(i, j)``, ``i < j``, each named by the slot it
    started in (cluster ``j`` joins cluster ``i``), in order. O(N²·C) time: after a merge only the merged cluster's
    row of the distance matrix is recomputed.
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
    for _ in range(n - max(keep, 1)):
        flat = int(np.argmin(d))  # row-major: ties go to the lowest pair, so the merge order is reproducible
        i, j = divmod(flat, n)
        if not np.isfinite(d[i, j]) or 1.0 - d[i, j] < tau:
            break
        if distances is not None:
            distances.append(float(d[i, j]))
        i, j = min(i, j), max(i, j)
        if pairs is not None:
            pairs.append((i, j))
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


@dataclass(frozen=True)
class MergeOrder:
    """Every merge a clip's clustering (:func:`~studio.targets.keyframes.merge_order`) would make, in its order
    (which does not depend on ``tau``): the keyframes at any ``tau`` at once (their count under a slider, the
    clusters of "Apply τ"), without embedding or merging again. The merging stops where ``tau`` says: the clusters
    are those :func:`merge_clusters` makes at it."""

    d: np.ndarray  # (N − 1,) the normalised distance of each merge, in order (N frames)
    pairs: np.ndarray  # (N − 1, 2) int64: the clusters (i < j, named by their first slot) each merge joins, in order
    embeddings: np.ndarray  # (N, C) float64 the frames' embeddings: a keyframe is the member nearest its mean
    changes_shape: bool  # the two least alike frames' crops overlap less than one_iou: never one keyframe

    def merges(self, tau: float) -> int:
        """How many of the merges are made at ``tau``: up to the first pair less similar than ``tau``, and never the
        last one when the shape changes through the clip (two keyframes are kept)."""
        stop = np.flatnonzero(1.0 - self.d < tau)
        made = int(stop[0]) if len(stop) else len(self.d)
        return made - 1 if made == len(self.d) and made and self.changes_shape else made

    def count(self, tau: float) -> int:
        """How many keyframes the clustering makes at ``tau`` (the same comparison, the same merges)."""
        return len(self.d) + 1 - self.merges(tau)

    def clusters(self, tau: float) -> Clusters:
        """The :class:`Clusters` at ``tau``: the first :meth:`merges` merges replayed, a representative per cluster."""
        e = self.embeddings
        members: list[list[int]] = [[i] for i in range(len(e))]
        alive = np.ones(len(e), bool)
        for i, j in self.pairs[: self.merges(tau)].tolist():
            members[i] = sorted(members[i] + members[j])
            alive[j] = False
        groups = sorted((members[i] for i in np.flatnonzero(alive)), key=lambda m: m[0])
        assignment = np.empty(len(e), np.int64)
        reps = np.empty(len(groups), np.int64)
        for k, group in enumerate(groups):
            assignment[group] = k
            centre = e[group].mean(axis=0)
            reps[k] = group[int(np.argmin(np.linalg.norm(e[group] - centre, axis=1)))]
        log.debug("%d frames → %d keyframes (tau %.3f)", len(e), len(groups), tau)
        return Clusters(assignment=assignment, representatives=reps, members=groups)
