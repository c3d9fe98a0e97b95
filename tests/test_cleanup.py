"""Cleaning photographed shadows (``studio.targets.cleanup``): run lengths, ruled lines and specks go, legs and
tails stay."""

from __future__ import annotations

import numpy as np

from studio.targets.cleanup import clean_shadow, remove_specks, ruled_lines, run_lengths

# --- cleaning photographed shadows -------------------------------------------------------------------------------


def test_run_lengths_by_hand():
    m = np.array([[1, 1, 0, 1], [0, 1, 0, 0]], np.uint8)
    assert run_lengths(m, 1).tolist() == [[2, 2, 0, 1], [0, 1, 0, 0]]
    assert run_lengths(m, 0).tolist() == [[1, 2, 0, 1], [0, 2, 0, 0]]


def test_ruled_line_goes_legs_and_tail_stay():
    m = np.zeros((100, 150), np.uint8)
    m[30:60, 40:110] = 1  # body
    m[60:85, 45:49] = 1  # a leg down to the ground line
    m[40:44, 10:40] = 1  # a thin tail
    m[85:88, :] = 1  # a rule across the frame, touching the leg
    m[0:2, :] = 1  # the frame's edge
    lines = ruled_lines(m)
    assert lines[86, :40].all() and lines[86, 60:].all() and lines[0, 75]
    assert not lines[30:60].any() and not lines[60:85].any() and not lines[40:44, 10:40].any()
    clean = clean_shadow(m)
    assert clean[30:60, 40:110].all() and clean[60:85, 45:49].all() and clean[40:44, 12:40].all()
    assert not clean[85:88, 60:].any() and not clean[0:2].any()
    speck = np.zeros((40, 40), np.uint8)
    speck[5:25, 5:25] = 1
    speck[30, 30] = 1
    assert remove_specks(speck, 2)[30, 30] == 0 and remove_specks(speck, 2)[5:25, 5:25].all()
