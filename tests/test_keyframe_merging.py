"""Keyframe merging: identical frames group in order of first appearance, τ is monotone and its extremes hold,
representatives are nearest their cluster mean, the fast merge matches a slow reference, the clusters cut from a merge
order at any τ are those of merging until τ, the PCA is scikit-learn's bit for bit without its import, and the
least-alike pair's IoU is the all-pairs minimum."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from keyframes_support import ellipses  # this folder's helper

from studio.targets.expressive import expressive_masks
from studio.targets.keyframes import KeyframeConfig, cluster_keyframes, embed
from studio.targets.merging import merge_clusters

S = 32


def shape_a() -> np.ndarray:
    m = np.zeros((S, S), np.uint8)
    m[20:30, 2:30] = 1
    m[4:20, 4:8] = 1  # body with a raised bar on the left
    return m


def shape_b() -> np.ndarray:
    m = np.zeros((S, S), np.uint8)
    m[20:30, 2:30] = 1
    m[10:20, 18:30] = 1  # the same body with a block on the right
    return m


def slow_merge(e: np.ndarray, tau: float) -> list[list[int]]:
    """Reference: recompute every cluster mean and every pairwise distance before each merge."""
    dist = np.linalg.norm(e[:, None] - e[None], axis=-1)
    scale = dist.max() or 1.0
    clusters = [[i] for i in range(len(e))]
    while len(clusters) > 1:
        means = np.stack([e[c].mean(axis=0) for c in clusters])
        best = None
        for a in range(len(clusters)):
            for b in range(a + 1, len(clusters)):
                d = np.linalg.norm(means[a] - means[b]) / scale
                key = (d, min(clusters[a]), min(clusters[b]))
                if best is None or key < best[0]:
                    best = (key, a, b)
        (d, *_), a, b = best
        if 1 - d < tau:
            break
        clusters[a] = sorted(clusters[a] + clusters[b])
        del clusters[b]
    return sorted(clusters, key=lambda c: c[0])


def test_identical_frames_group_in_order_of_first_appearance():
    a, b = shape_a(), shape_b()
    masks = np.stack([a, a, a, b, b, a])
    c = cluster_keyframes(expressive_masks(masks))
    assert c.count == 2
    np.testing.assert_array_equal(c.assignment, [0, 0, 0, 1, 1, 0])
    assert c.members == [[0, 1, 2, 5], [3, 4]]
    assert c.representatives[0] in c.members[0] and c.representatives[1] in c.members[1]
    np.testing.assert_array_equal(c.representatives, [0, 3])  # ties go to the first member
    assert c.reduction == pytest.approx(1 - 2 / 6)


def test_tau_extremes():
    rng = np.random.default_rng(0)
    masks = (rng.random((7, 16, 16)) < 0.4).astype(np.uint8)
    everything = KeyframeConfig(tau=0.0, one_iou=0.0)  # d ≤ 1 always: everything merges (no floor on the change)
    assert cluster_keyframes(masks, everything).count == 1
    assert cluster_keyframes(masks, KeyframeConfig(tau=0.0)).count == 2  # random frames: their shapes change
    masks[3] = masks[1]
    c = cluster_keyframes(masks, KeyframeConfig(tau=1.0))  # only identical frames merge
    assert c.count == 6 and c.assignment[3] == c.assignment[1]
    assert cluster_keyframes(np.zeros((4, 8, 8), np.uint8)).count == 1  # nothing expressive: one keyframe


random_sequences = st.integers(2, 9).flatmap(
    lambda n: st.lists(st.lists(st.booleans(), min_size=64, max_size=64), min_size=n, max_size=n)
)


@pytest.mark.slow
@settings(max_examples=40, deadline=None)
@given(seq=random_sequences, t1=st.floats(0, 1), t2=st.floats(0, 1))
def test_higher_tau_never_gives_fewer_clusters(seq, t1, t2):
    masks = np.array(seq, np.uint8).reshape(-1, 8, 8)
    lo, hi = sorted((t1, t2))
    counts = [cluster_keyframes(masks, KeyframeConfig(tau=t)).count for t in (lo, hi)]
    assert counts[1] >= counts[0]


@pytest.mark.slow
@settings(max_examples=25, deadline=None)
@given(seq=random_sequences, tau=st.floats(0, 1))
def test_representative_is_nearest_its_cluster_mean(seq, tau):
    masks = np.array(seq, np.uint8).reshape(-1, 8, 8)
    cfg = KeyframeConfig(tau=tau)
    c = cluster_keyframes(masks, cfg)
    e = embed(masks, cfg)
    assert sorted(i for m in c.members for i in m) == list(range(len(masks)))
    assert [m[0] for m in c.members] == sorted(m[0] for m in c.members)  # first-appearance order
    for k, (group, rep) in enumerate(zip(c.members, c.representatives, strict=True)):
        assert rep in group and (c.assignment[group] == k).all()
        d = np.linalg.norm(e[group] - e[group].mean(axis=0), axis=1)
        assert np.linalg.norm(e[rep] - e[group].mean(axis=0)) <= d.min() + 1e-9


def test_fast_merge_matches_slow_reference():
    rng = np.random.default_rng(1)
    for n, tau in ((12, 0.3), (20, 0.5), (25, 0.7)):
        centres = rng.normal(size=(4, 6))
        e = centres[rng.integers(0, 4, n)] + 0.3 * rng.normal(size=(n, 6))
        assert merge_clusters(e, tau) == slow_merge(e, tau)


def test_merging_hundreds_of_frames_is_fast():
    rng = np.random.default_rng(2)
    e = rng.normal(size=(400, 50))
    start = time.perf_counter()
    clusters = merge_clusters(e, 0.2)
    assert time.perf_counter() - start < 5.0  # a naive O(N³·C) merge takes minutes here
    assert sorted(i for c in clusters for i in c) == list(range(400))


def test_clustering_imports_no_scikit_learn_and_a_still_no_svd():
    """The PCA is the studio's own: a clip clusters without scikit-learn's import (1.2 s), and a still (one frame,
    nothing to project) without even SciPy's linear algebra."""
    code = (
        "import sys, numpy as np\n"
        "from studio.targets.keyframes import cluster_keyframes\n"
        "m = np.zeros((1, 32, 32), np.uint8); m[0, 8:20, 10:24] = 1\n"
        "c = cluster_keyframes(m)\n"
        "print(c.assignment.tolist(), c.representatives.tolist(), 'scipy.linalg' in sys.modules)\n"
        "clip = np.stack([np.roll(m[0], 3 * i, axis=1) * (i % 3 + 1 > 1) for i in range(6)])\n"
        "print(cluster_keyframes(clip).count, 'scipy.linalg' in sys.modules, 'sklearn' in sys.modules)"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.split() == ["[0]", "[0]", "False", "2", "True", "False"], done.stdout


def test_the_pca_is_scikit_learns_bit_for_bit():
    """:func:`pca` against scikit-learn's ``PCA(svd_solver="full")`` (the reference, installed with the tests): the
    same embeddings to the last bit, so clustering made with either merges the same pairs, near ties included."""
    from sklearn.decomposition import PCA

    from studio.targets.keyframes import pca

    rng = np.random.default_rng(7)
    for n_frames, side, n in ((2, 8, 2), (9, 16, 9), (30, 24, 30), (70, 24, 50), (12, 64, 5)):
        x = (rng.random((n_frames, side * side)) < rng.uniform(0.1, 0.6)).astype(np.float64)
        x = np.round(x * rng.random(x.shape[1]), 9)  # blurred-crop-like values
        y = x[rng.permutation(n_frames)[: max(1, n_frames // 2)]]
        want = PCA(n_components=n, svd_solver="full").fit(x).transform(y)
        assert np.array_equal(pca(x, y, n), want), (n_frames, side, n)
    masks = ellipses(np.geomspace(0.25, 4.0, 12))
    assert embed(masks).shape == (12, 12)


def direct_clusters(e: np.ndarray, tau: float, changes: bool) -> tuple[list[list[int]], list[int]]:
    """Reference for the clusters cut from a merge order: embeddings ``e (N, C)`` merged until the pair is less
    similar than ``tau`` (:func:`merge_clusters` stopping there), two clusters kept when the shape ``changes``; each
    cluster's member nearest its mean embedding → (members, representatives)."""
    members = merge_clusters(e, tau)
    if len(members) == 1 and len(e) > 1 and changes:
        members = merge_clusters(e, tau, keep=2)
    reps = [g[int(np.argmin(np.linalg.norm(e[g] - e[g].mean(axis=0), axis=1)))] for g in members]
    return members, reps


def test_clusters_cut_from_the_merge_order_are_the_direct_merge_at_every_tau():
    """``merge_order(...)`` at any τ (the Keyframes panel's live count, "Apply τ", ``cluster_keyframes``) makes the
    clusters that merging until τ makes (:func:`direct_clusters`): on the boundaries 1 − d of each merge and between
    them, for shapes that change (the two-keyframe rule holds), steady shapes, random frames and a single frame."""
    from studio.targets.keyframes import merge_order, most_different_iou

    rng = np.random.default_rng(5)
    changing = ellipses(np.geomspace(0.25, 4.0, 12))
    steady = ellipses(np.full(8, 0.5))
    noisy = (rng.random((15, 16, 16)) < 0.4).astype(np.uint8)
    checked = 0
    for masks in (changing, steady, noisy, changing[:1]):
        cfg = KeyframeConfig()
        order = merge_order(masks, cfg)
        e, changes = embed(masks, cfg), most_different_iou(masks, cfg) < cfg.one_iou
        assert np.array_equal(order.embeddings, e) and order.changes_shape == (changes and len(masks) > 1)
        assert len(order.d) == len(masks) - 1 and order.pairs.shape == (len(masks) - 1, 2)
        edges = 1.0 - order.d
        taus = np.unique(np.clip(np.concatenate([edges, edges + 1e-9, edges - 1e-9, np.linspace(0, 1, 21)]), 0, 1))
        for tau in taus:
            members, reps = direct_clusters(e, float(tau), changes)
            cut = order.clusters(float(tau))
            assert (cut.members, cut.representatives.tolist()) == (members, reps), (len(masks), tau)
            assert order.count(float(tau)) == len(members)
            checked += 1
        assert cluster_keyframes(masks, KeyframeConfig(tau=0.5)).members == order.clusters(0.5).members
    assert checked > 60
    assert merge_order(changing).changes_shape and not merge_order(steady).changes_shape
    assert merge_order(changing).count(0.0) == 2 and merge_order(steady).count(0.0) == 1


def test_most_different_iou_is_the_all_pairs_minimum():
    """The row-at-a-time soft IoU equals every pair's at once (the (N, N, size²) reference, small N)."""
    from studio.targets.keyframes import _crops, most_different_iou

    rng = np.random.default_rng(6)
    for masks in (ellipses(np.geomspace(0.5, 2.0, 7)), (rng.random((9, 24, 24)) < 0.3).astype(np.uint8)):
        cfg = KeyframeConfig()
        c = np.stack(_crops(masks, cfg, None)).reshape(len(masks), -1)
        lo = np.minimum(c[:, None, :], c[None, :, :]).sum(axis=-1)
        hi = np.maximum(c[:, None, :], c[None, :, :]).sum(axis=-1)
        reference = float(np.where(hi > 0, lo / np.maximum(hi, 1e-12), 1.0).min())
        assert most_different_iou(masks, cfg) == pytest.approx(reference, abs=1e-12)
        for below in (reference - 0.01, reference + 0.01):  # stopping early answers "is it under below?" the same
            assert (most_different_iou(masks, cfg, below=below) < below) == (reference < below)
