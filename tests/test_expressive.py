"""Expressive regions on synthetic sequences: what moves, every hole, and painted strokes that never replace."""

from __future__ import annotations

import numpy as np
import pytest

from studio.targets.expressive import combine, expressive_masks, holes_region, moving_region

S = 32


def bar_sequence(n: int = 4) -> np.ndarray:
    """A fixed body (rows 20-27) with a bar (rows 8-19, 3 columns wide) that slides right by 4 px a frame."""
    masks = np.zeros((n, S, S), np.uint8)
    masks[:, 20:28, 4:28] = 1
    for i in range(n):
        masks[i, 8:20, 6 + 4 * i : 9 + 4 * i] = 1
    return masks


def ring(outer: int = 10, inner: int = 4, size: int = S) -> np.ndarray:
    yy, xx = np.mgrid[:size, :size] - (size - 1) / 2
    r = np.hypot(yy, xx)
    return ((r <= outer) & (r > inner)).astype(np.uint8)


def test_moving_bar_gives_only_the_moving_part():
    masks = bar_sequence()
    expr = expressive_masks(masks)
    assert expr.shape == masks.shape and expr.dtype == np.uint8
    body = np.zeros((S, S), bool)
    body[20:28, 4:28] = True
    for i in range(len(masks)):
        bar = np.zeros((S, S), bool)
        bar[8:20, 6 + 4 * i : 9 + 4 * i] = True
        np.testing.assert_array_equal(expr[i].astype(bool), bar)  # the bar, never the body every frame shares
        assert not expr[i][body].any()


def test_pixels_shared_by_all_but_one_frame_still_move():
    masks = np.ones((3, S, S), np.uint8)
    masks[:, 0, :] = 0  # the border row is backdrop everywhere, so the rest is not a hole
    masks[1, 10:12, 10:12] = 0  # frame 1 lacks a patch the others have: in those, the patch moves
    expr = moving_region(masks)
    assert expr[0, 10:12, 10:12].all() and expr[2, 10:12, 10:12].all()
    assert expr[0].sum() == 4 and expr[2].sum() == 4 and expr[1].sum() == 0


def test_single_frame_has_no_motion_but_keeps_its_holes():
    m = ring()[None]
    assert moving_region(m).sum() == 0
    np.testing.assert_array_equal(expressive_masks(m), holes_region(m))
    assert holes_region(m).sum() > 0


def test_ring_hole_is_counted_even_when_static():
    masks = np.repeat(ring()[None], 3, axis=0)  # the ring never moves: only its hole is expressive
    expr = expressive_masks(masks)
    yy, xx = np.mgrid[:S, :S] - (S - 1) / 2
    hole = np.hypot(yy, xx) <= 4
    for e in expr:
        np.testing.assert_array_equal(e.astype(bool), hole)


def test_gap_open_to_the_border_is_no_hole():
    c = ring()
    c[: S // 2, S // 2 - 1 : S // 2 + 1] = 0  # cut the ring open up to the top border: a "C", no hole
    assert holes_region(c[None]).sum() == 0


def test_hole_and_motion_together():
    masks = bar_sequence(3)
    masks[:, 22:26, 12:16] = 0  # a window in the body, enclosed on every side
    expr = expressive_masks(masks)
    assert expr[:, 22:26, 12:16].all()  # the hole
    assert not expr[:, 20:22, 4:28].any()  # the static body around it
    assert expr[1, 8:20, 10:13].all()  # the bar where it is in frame 1


def test_combine_adds_and_erases_without_replacing():
    auto = expressive_masks(bar_sequence())
    add = np.zeros((S, S), np.uint8)
    add[0:4, 0:4] = 1  # one stroke layer for every frame
    erase = np.zeros_like(auto)
    erase[2, 8:12] = 1  # erase the top of frame 2's bar only
    before = (auto.copy(), add.copy(), erase.copy())
    out = combine(auto, add, erase)
    np.testing.assert_array_equal(out, (auto.astype(bool) | add.astype(bool)) & ~erase.astype(bool))
    assert out[:, 0:4, 0:4].all()  # additions painted in
    assert not out[2, 8:12].any() and out[2, 12:20].any()  # erased part gone, the rest of the automatic mask kept
    assert out[0].sum() == auto[0].sum() + 16  # other frames: automatic mask plus the stroke, nothing replaced
    for a, b in zip(before, (auto, add, erase), strict=True):
        np.testing.assert_array_equal(a, b)  # inputs untouched: the strokes survive a re-run


def test_combine_erasure_wins_and_none_is_identity():
    auto = ring()
    np.testing.assert_array_equal(combine(auto), auto)
    both = np.ones_like(auto)
    assert combine(auto, additions=both, erasures=both).sum() == 0  # painted out beats painted in
    assert combine(auto, additions=both).all()


def test_combine_refuses_strokes_of_another_size():
    with pytest.raises(ValueError, match="do not fit"):
        combine(np.zeros((3, S, S)), additions=np.zeros((S + 1, S)))
    with pytest.raises(ValueError, match="sequence"):
        expressive_masks(np.zeros((S, S), np.uint8))
