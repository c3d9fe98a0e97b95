"""Keyframe clustering: identical frames group, τ is monotone, representatives are nearest their cluster mean, the
fast merge matches a slow reference, frames are compared by shape in their own aligned crops (shifting and scaling
them changes nothing, a changing shape is not one keyframe, empty masks are fine), and the default τ reproduces the
paper's reductions on the DAVIS sequences."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from studio.targets.expressive import expressive_masks
from studio.targets.keyframes import KeyframeConfig, aligned_crop, cluster_keyframes, embed, merge_clusters

S = 32
DAVIS = ("bear", "blackswan", "camel", "cows", "dog", "flamingo")  # the paper's six videos


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


def figure(S: int = 64) -> np.ndarray:
    """A lopsided shape: a body, a head up on the right and a tail on the left."""
    m = np.zeros((S, S), np.uint8)
    cv2.ellipse(m, (30, 34), (14, 7), 0, 0, 360, 1, -1)
    cv2.circle(m, (45, 25), 5, 1, -1)
    m[32:35, 10:18] = 1
    return m


def moved(mask: np.ndarray, scale: float, dx: float, dy: float) -> np.ndarray:
    """``mask`` scaled by ``scale`` about the origin and shifted by ``(dx, dy)`` px within the same frame."""
    a = np.float32([[scale, 0, dx], [0, scale, dy]])
    out = cv2.warpAffine(mask.astype(np.float32), a, mask.shape[::-1], flags=cv2.INTER_LINEAR)
    return (out >= 0.5).astype(np.uint8)


def distinct_shapes(S: int = 64) -> list[np.ndarray]:
    """Three clearly different shapes, each filling part of a frame's upper left."""
    bar = np.zeros((S, S), np.uint8)
    bar[4:36, 8:22] = 1  # a tall bar
    ring = np.zeros((S, S), np.uint8)
    cv2.circle(ring, (22, 22), 18, 1, -1)
    cv2.circle(ring, (22, 22), 8, 0, -1)  # a ring
    return [np.roll(figure(S), (-14, -8), (0, 1)), bar, ring]


def test_aligned_crop_is_the_losses_crop_and_ignores_position():
    m = np.zeros((64, 64), np.uint8)
    m[10:20, 5:45] = 1  # 10 × 40 box; pad 5 px at 256 = 1.25 px at 64: square side 42.5 about (25, 15)
    c = aligned_crop(m, 34)
    assert c.shape == (34, 34) and c.dtype == np.float64
    np.testing.assert_allclose(c.sum() * (42.5 / 34) ** 2, m.sum())  # area kept: an exact area resampling
    rows = np.flatnonzero(c.max(axis=1) > 0.5)
    assert rows.min() > 10 and rows.max() < 23  # the bar sits in the middle rows, aspect ratio kept
    np.testing.assert_array_equal(aligned_crop(np.roll(m, (30, 12), (0, 1)), 34), c)  # a shift changes nothing
    big = cv2.resize(m, (128, 128), interpolation=cv2.INTER_NEAREST)  # twice the size (the pad scales with the side)
    assert np.abs(aligned_crop(big, 34) - c).max() < 1e-9
    np.testing.assert_array_equal(aligned_crop(np.zeros((16, 16), np.uint8), 8), np.zeros((8, 8)))  # empty: no crash


def test_clusters_ignore_shifting_and_scaling_the_frames():
    """The same shapes anywhere in the frame and at 0.7 × the size cluster as they do in place: the old whole-frame
    resize grouped frames by where their shadows were."""
    a, b, c = distinct_shapes()
    seq = [a, a, b, b, b, a, c, c, b]
    rng = np.random.default_rng(3)
    shifted = [moved(m, 0.7, *rng.uniform(0, 18, 2)) for m in seq]  # each frame its own shift, sub-pixel phases too
    assert all(x.sum() < 0.6 * m.sum() for x, m in zip(shifted, seq, strict=True))  # really scaled (0.49 × area)
    cfg = KeyframeConfig()
    plain, moved_c = cluster_keyframes(np.stack(seq), cfg), cluster_keyframes(np.stack(shifted), cfg)
    assert plain.members == [[0, 1, 5], [2, 3, 4, 8], [6, 7]]
    assert moved_c.members == plain.members
    e1, e2 = embed(np.stack(seq), cfg), embed(np.stack(shifted), cfg)
    d1, d2 = (np.linalg.norm(e[:, None] - e[None], axis=-1) for e in (e1, e2))
    np.testing.assert_allclose(d2 / d2.max(), d1 / d1.max(), atol=0.1)  # the same geometry up to resampling
    wander = np.stack([np.roll(a, (3 * i, i), (0, 1)) for i in range(12)])  # one shape walking across (no wrap)
    assert cluster_keyframes(wander, cfg).count == 1
    grow = np.stack([moved(figure(), s, 40 * (1 - s), 30 * (1 - s)) for s in (0.6, 0.7, 0.8, 0.9, 1.0)])
    grown = cluster_keyframes(np.concatenate([grow, np.stack([b] * 5)]), cfg)  # one shape at 0.6-1 × its size
    assert grown.members == [[0, 1, 2, 3, 4], [5, 6, 7, 8, 9]]


def ellipses(aspects, S: int = 64) -> np.ndarray:
    """One ellipse of constant area per aspect ratio (width / height), drifting down and right across the frame."""
    out = np.zeros((len(aspects), S, S), np.uint8)
    for i, r in enumerate(aspects):
        cv2.ellipse(out[i], (14 + 3 * i, 16 + 2 * i), (round(10 * r**0.5), round(10 / r**0.5)), 0, 0, 360, 1, -1)
    return out


def test_a_changing_shape_is_not_one_keyframe():
    """An ellipse turning steadily from tall (1:4) to wide (4:1) while it drifts across the frame: more than one
    keyframe, in time order; the same ellipse drifting without changing: one keyframe."""
    c = cluster_keyframes(ellipses(np.geomspace(0.25, 4.0, 12)))
    assert c.count > 1
    assert all(m == list(range(m[0], m[-1] + 1)) for m in c.members)  # contiguous stretches of the clip
    assert cluster_keyframes(ellipses(np.full(12, 0.5))).count == 1


def test_empty_masks_cluster_without_crashing():
    """Frames with no expressive pixel have an empty crop: they group together, apart from the shaped frames."""
    a, b, _ = distinct_shapes()
    z = np.zeros_like(a)
    c = cluster_keyframes(np.stack([z, a, a, z, b, z]))
    assert c.members == [[0, 3, 5], [1, 2], [4]]
    assert cluster_keyframes(np.zeros((1, 16, 16), np.uint8)).count == 1
    np.testing.assert_array_equal(embed(np.zeros((3, 16, 16), np.uint8)), np.zeros((3, 1)))


def test_shadow_boxes_see_where_the_expressive_part_is_on_the_shadow():
    """A still body with an arm in three places (the expressive part is the arm alone, the same disc each time):
    cropped by the frames' shadow boxes, as the losses crop it, the three arm positions are three keyframes; and
    the whole shadow shifted across the frame changes nothing."""
    yy, xx = np.mgrid[:64, :64]
    frames = []
    for ang in (-0.8, -0.8, 0.0, 0.0, 0.0, 0.8, 0.8, -0.8):
        m = ((yy - 40) ** 2 + (xx - 32) ** 2 < 12**2).astype(np.uint8)
        m |= ((yy - 40 + 20 * np.cos(ang)) ** 2 + (xx - 32 - 20 * np.sin(ang)) ** 2 < 6**2).astype(np.uint8)
        frames.append(m)
    shadows = np.stack(frames)
    expressive = expressive_masks(shadows)
    c = cluster_keyframes(expressive, shadows=shadows)
    assert c.members == [[0, 1, 7], [2, 3, 4], [5, 6]]
    assert cluster_keyframes(expressive).count < 3  # in its own box the disc is the same wherever the arm is
    moved_by = [(0, 0), (-5, 3), (2, -7), (-9, 0), (0, 5), (-3, -3), (1, 1), (-6, 8)]
    rolled_sh = np.stack([np.roll(m, d, (0, 1)) for m, d in zip(shadows, moved_by, strict=True)])
    rolled_ex = np.stack([np.roll(m, d, (0, 1)) for m, d in zip(expressive, moved_by, strict=True)])
    assert cluster_keyframes(rolled_ex, shadows=rolled_sh).members == c.members
    with pytest.raises(ValueError, match="shape"):
        embed(expressive, shadows=shadows[:3])


def load_davis(folder, hz: float = 4.0) -> np.ndarray:
    from studio.targets.video import VideoConfig, load_video

    return load_video(folder, VideoConfig(hz=hz)).masks


@pytest.mark.slow
@pytest.mark.parametrize("name", DAVIS)
def test_davis_reductions_at_default_tau(shared_targets, name):
    """Each sequence keeps the paper's 63–92 % at 4 Hz and more than one keyframe (as in the paper), cropped by its
    own box or by its frames' shadow boxes alike."""
    folder = shared_targets / "davis" / name
    if not folder.is_dir():
        pytest.skip(f"DAVIS masks not found at {folder}")
    masks = load_davis(folder)
    expressive = expressive_masks(masks)
    assert 8 <= len(masks) <= 20  # ~4 Hz from 24 fps: frame counts of the paper's order
    for shadows in (None, masks):
        c = cluster_keyframes(expressive, shadows=shadows)
        assert c.count >= 2 and 0.63 <= c.reduction <= 0.92, f"{name}: {len(masks)} frames → {c.count} keyframes"


@pytest.mark.slow
def test_keyframes_verb_end_to_end(shared_targets, tmp_path):
    src = shared_targets / "davis" / "blackswan"
    out = tmp_path / "kf"
    r = subprocess.run(
        [sys.executable, "-m", "studio.cli", "keyframes", str(src), "--out", str(out)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    lines = r.stdout.strip().splitlines()
    summary = json.loads(lines[-1])
    n, k = summary["frames"], summary["keyframes"]
    assert len(summary["assignment"]) == n and len(summary["representatives"]) == k
    assert sorted(set(summary["assignment"])) == list(range(k))
    assert summary["assignment"][0] == 0
    assert len(lines) - 1 >= k  # one line per cluster before the JSON
    sheet = cv2.imread(summary["sheet"])
    counts = np.bincount(summary["assignment"])
    rows = int(sum(-(-c // 16) for c in counts))  # one row per keyframe, wrapped after 16 tiles of 96 px + 4 px gap
    assert sheet is not None and sheet.shape == (rows * 100 - 4, min(counts.max(), 16) * 100 - 4, 3)
    assert (sheet[..., 0] != sheet[..., 2]).any()  # the expressive tint is there


def test_sheet_rows_put_the_representative_first():
    from studio.review.sheets import REPRESENTATIVE, keyframe_sheet

    masks = np.zeros((5, 16, 16), np.uint8)
    masks[:, 4:12, 4:12] = 1
    img = keyframe_sheet(masks, masks, [[0, 2, 3], [1, 4]], [2, 4], tile=20, columns=2)
    assert img.shape == (3 * 24 - 4, 2 * 24 - 4, 3)  # rows: [2, 0], [3], [4, 1]
    framed = [tuple(img[r * 24, c * 24]) for r in range(3) for c in range(2)]
    assert framed[0] == REPRESENTATIVE and framed[4] == REPRESENTATIVE  # row starts of keyframes 0 and 1
    assert framed[1] != REPRESENTATIVE and framed[5] != REPRESENTATIVE


def test_keyframes_verb_refuses_a_bad_tau(tmp_path):
    r = subprocess.run(
        [sys.executable, "-m", "studio.cli", "keyframes", str(tmp_path), "--tau", "1.5"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert r.returncode == 2 and "Traceback" not in r.stderr and "tau" in r.stderr


def test_the_crop_pad_is_the_losses():
    from studio.imitate.config import LossConfig
    from studio.targets.keyframes import PAD

    assert PAD == LossConfig().pad


def test_a_steady_change_of_shape_keeps_two_keyframes_at_any_tau():
    """An ellipse going steadily from 1:2 to 2:1 blends evenly, so merging relative to the clip's own largest
    change would take it whole at a low tau; its first and last crops overlap far less than one_iou: two keyframes."""
    import cv2

    from studio.targets.keyframes import KeyframeConfig, cluster_keyframes, most_different_iou

    frames = []
    for i, r in enumerate(np.linspace(0.5, 2.0, 12)):
        m = np.zeros((96, 96), np.uint8)
        cv2.ellipse(m, (30 + 3 * i, 48), (int(20 * r**0.5), int(20 / r**0.5)), 0, 0, 360, 1, -1)
        frames.append(m)
    masks = np.stack(frames)
    cfg = KeyframeConfig(tau=0.05)
    assert most_different_iou(masks, cfg) < cfg.one_iou
    assert cluster_keyframes(masks, cfg).count == 2
    still = np.stack([frames[0]] * 6)
    assert most_different_iou(still, cfg) == 1.0 and cluster_keyframes(still, cfg).count == 1


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
