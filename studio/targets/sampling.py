"""Which source frames a video's samples are: sample ``k`` is the source frame whose start is nearest ``k / hz``
(ties go to the later frame), for every ``k`` whose time falls before the middle of the last frame, so each sampled
frame lies within half a source frame of ``k / hz`` (DESIGN §4 "Video targets"). Pure compute; the readers are
:mod:`studio.targets.footage`'s."""

from __future__ import annotations

import numpy as np

__all__ = ["gif_sample", "sample_times"]


def sample_times(duration_s: float, fps: float, hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample a constant-rate source (``round(duration_s · fps)`` frames at ``fps``) at ``hz``.

    Returns ``(times (K,) s, indices (K,) int)``: frame ``indices[k]`` starts at ``times[k] = indices[k] / fps``,
    the frame nearest ``k / hz`` (DESIGN §4), for every ``k`` that falls within the source.
    """
    if fps <= 0 or hz <= 0:
        raise ValueError("fps and hz must be positive")
    n = int(round(duration_s * fps))
    return _sample(np.arange(n) / fps, (n - 0.5) / fps, hz)


def gif_sample(durations_s: np.ndarray, hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Sample a GIF whose frames show for ``durations_s`` (N,) s at ``hz``: ``(times (K,), indices (K,))``."""
    d = np.asarray(durations_s, dtype=np.float64)
    if len(d) == 0:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    starts = np.concatenate([[0.0], np.cumsum(d)[:-1]])
    return _sample(starts, starts[-1] + d[-1] / 2, hz)


def _sample(starts: np.ndarray, end_s: float, hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Frames nearest ``k / hz`` for ``k / hz < end_s`` among frames starting at ``starts`` (ties: later frame)."""
    if hz <= 0:
        raise ValueError("hz must be positive")
    if len(starts) == 0 or end_s <= 0:
        return np.zeros(0), np.zeros(0, dtype=np.int64)
    k_max = int(np.ceil(end_s * hz - 1e-9))  # k / hz < end_s
    wanted = np.arange(k_max) / hz
    middles = (starts[1:] + starts[:-1]) / 2
    idx = np.searchsorted(middles, wanted + 1e-9, side="right")  # 1e-9 s: float noise never flips a tie
    return starts[idx], idx.astype(np.int64)
