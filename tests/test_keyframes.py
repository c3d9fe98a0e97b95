"""Keyframe clustering: identical frames group, τ is monotone, representatives are nearest their cluster mean, the
fast merge matches a slow reference, and the default τ reproduces the paper's reductions on the DAVIS sequences."""

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
from studio.targets.keyframes import KeyframeConfig, cluster_keyframes, embed, merge_clusters

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
    assert cluster_keyframes(masks, KeyframeConfig(tau=0.0)).count == 1  # d ≤ 1 always: everything merges
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


def load_davis(folder, hz: float = 4.0) -> np.ndarray:
    from studio.targets.video import VideoConfig, load_video

    return load_video(folder, VideoConfig(hz=hz)).masks


@pytest.mark.slow
@pytest.mark.parametrize("name", DAVIS)
def test_davis_reductions_at_default_tau(shared_targets, name):
    masks = load_davis(shared_targets / "davis" / name)
    c = cluster_keyframes(expressive_masks(masks))
    assert 8 <= len(masks) <= 20  # ~4 Hz from 24 fps: frame counts of the paper's order
    assert 0.60 <= c.reduction <= 0.95, f"{name}: {len(masks)} frames → {c.count} keyframes"


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
