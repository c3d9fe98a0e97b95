"""Which source frames a video's samples are (``studio.targets.sampling``): by hand, and for random rates and GIF
durations (hypothesis); and the natural order of frame files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from studio.targets.footage import natural_key
from studio.targets.sampling import gif_sample, sample_times

# --- sampling arithmetic ----------------------------------------------------------------------------------------


def test_sample_times_by_hand():
    times, idx = sample_times(1.0, 24, 4)  # DAVIS at the default rate: every 6th frame
    assert idx.tolist() == [0, 6, 12, 18] and np.allclose(times, [0, 0.25, 0.5, 0.75])
    times, idx = sample_times(82 / 30, 30, 4)  # bear.mp4: 7.5 frames a sample, ties to the later frame
    assert idx.tolist() == [0, 8, 15, 23, 30, 38, 45, 53, 60, 68, 75]
    assert np.allclose(times, idx / 30)
    _, idx = sample_times(2.0, 10, 10)  # the source's own rate: every frame once
    assert idx.tolist() == list(range(20))
    _, idx = sample_times(1.0, 24, 2.35)  # the paper's slowest rate
    assert idx.tolist() == [0, 10, 20]
    assert len(sample_times(0.0, 24, 4)[0]) == 0
    with pytest.raises(ValueError):
        sample_times(1.0, 24, 0)


def test_gif_durations_by_hand():
    times, idx = gif_sample(np.full(11, 0.1), 4)  # Muybridge: 11 frames of 0.1 s
    assert idx.tolist() == [0, 3, 5, 8, 10] and np.allclose(times, [0, 0.3, 0.5, 0.8, 1.0])
    times, idx = gif_sample(np.array([0.5, 0.1, 0.1, 0.3]), 10)  # starts 0, .5, .6, .7; clock 1.0 s
    assert idx.tolist() == [0, 0, 0, 1, 1, 1, 2, 3, 3]
    assert np.allclose(times, [0, 0, 0, 0.5, 0.5, 0.5, 0.6, 0.7, 0.7])


@settings(max_examples=200, deadline=None)
@given(
    fps=st.floats(1, 120),
    share=st.floats(0.01, 1.0),
    n=st.integers(1, 400),
)
def test_sampled_times_within_half_a_frame(fps, share, n):
    hz = fps * share
    times, idx = sample_times(n / fps, fps, hz)
    k = np.arange(len(times))
    assert np.all(np.abs(times - k / hz) <= 0.5 / fps + 1e-9)
    assert np.all((idx >= 0) & (idx < n)) and np.all(np.diff(idx) > 0)  # hz ≤ fps: never a frame twice
    assert len(times) == int(np.sum(np.arange(int(n / share) + 2) / hz < (n - 0.5) / fps))


@settings(max_examples=150, deadline=None)
@given(durations=st.lists(st.floats(0.02, 1.0), min_size=1, max_size=40), hz=st.floats(0.5, 20))
def test_gif_sample_is_the_nearest_start(durations, hz):
    d = np.array(durations)
    starts = np.concatenate([[0.0], np.cumsum(d)[:-1]])
    times, idx = gif_sample(d, hz)
    wanted = np.arange(len(times)) / hz
    assert np.allclose(times, starts[idx])
    nearest = np.abs(starts[None, :] - wanted[:, None]).min(axis=1)
    assert np.all(np.abs(times - wanted) <= nearest + 1e-6)
    assert len(times) == 0 or wanted[-1] < starts[-1] + d[-1] / 2


def test_natural_order():
    names = [Path(f"f{i}.png") for i in (10, 2, 1)]
    assert [p.name for p in sorted(names, key=natural_key)] == ["f1.png", "f2.png", "f10.png"]
