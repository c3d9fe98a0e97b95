"""What a person looks at after a video's imitation: the frame contact sheet and the side-by-side video.

Pure numpy + OpenCV (the Rerun recording is :class:`studio.review.recording.ProjectRecording`). Frames follow the
rest of the studio's display convention (dark shadow on a light backdrop, expressive regions tinted,
:mod:`studio.review.sheets`).

- :func:`contact_sheet`: one ``target | shadow`` cell per sampled frame, labelled with its frame number, source
  time and keyframe; the shadow is that keyframe's pose, the pose the frame plays.
- :func:`write_side_by_side`: ``source frame | target mask | shadow`` at the source's rate: output frame ``m`` shows
  the sampled frame the caller says is played then beside the shadow it gives for that time (the project's show
  preview clock, :func:`studio.project.preview_clock.preview_clock`: the frames of the preview in the studio).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from studio.errors import ProgressFn, report
from studio.review.sheets import fit_tile, label, pair_sheet, shadow_tile, side_by_side, tint, write_png, write_video


def contact_sheet(
    masks: np.ndarray,
    expressive: np.ndarray,
    shadows: np.ndarray,
    times: np.ndarray,
    assignment: np.ndarray,
    tile: int = 96,
    columns: int = 6,
) -> np.ndarray:
    """Frames ``masks (N, S, S)`` with their ``expressive (N, S, S)`` regions, each next to ``shadows[i]`` (its
    keyframe's shadow, ``(N, R, R)``), labelled ``#i t s k<keyframe>`` → RGB ``(H, W, 3)`` uint8."""
    labels = [f"#{i} {float(t):.2f}s k{int(a)}" for i, (t, a) in enumerate(zip(times, assignment))]
    return pair_sheet(masks, expressive, list(shadows), labels, tile=tile, columns=columns)


def write_contact(path: str | Path, *args, **kwargs) -> Path:
    """:func:`contact_sheet` written as PNG (atomically); returns the path."""
    return write_png(path, contact_sheet(*args, **kwargs))


def video_times(end_s: float, fps: float) -> np.ndarray:
    """Times ``(M,)`` s of the output frames of a video lasting ``end_s`` at ``fps``: ``m / fps``, M = round(end·fps)
    (at least 1)."""
    return np.arange(max(1, int(round(end_s * fps)))) / fps


def frame_at(times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index ``(M,)`` of the sampled frame played at each time ``t (M,)``: the last frame with ``times[k] ≤ t``."""
    return np.clip(np.searchsorted(np.asarray(times), np.asarray(t) + 1e-9, side="right") - 1, 0, len(times) - 1)


def side_by_side_frame(source: np.ndarray | None, mask: np.ndarray, expressive: np.ndarray, shadow: np.ndarray,
                       text: str, tile: int) -> np.ndarray:  # fmt: skip
    """One RGB frame ``(T, 3T + 8, 3)``: source (RGB ``(S, S, 3)``, or the mask when None) | target mask (expressive
    tinted) | shadow, ``text`` written on the source panel."""
    src = fit_tile(source, tile) if source is not None else tint(mask, None, tile)
    return side_by_side([label(src, text), tint(mask, expressive, tile), shadow_tile(shadow, tile)], tile)


def write_side_by_side(
    path: str | Path,
    frames: Sequence[np.ndarray | None] | None,
    masks: np.ndarray,
    expressive: np.ndarray,
    played: np.ndarray,
    times: np.ndarray,
    shadows: np.ndarray,
    fps: float,
    tile: int = 160,
    progress: ProgressFn | None = None,
) -> Path:
    """Write ``side_by_side.mp4`` at ``fps``: output frame ``m`` (show time ``times[m]`` s) shows the sampled frame
    ``played[m]`` (``frames``: one ``(S, S, 3)`` RGB image or None per sampled frame, or None: the masks are shown;
    ``masks``/``expressive`` ``(N, S, S)``) beside ``shadows[m]`` (``(M, R, R)``). Progress events "video" m of M.
    Returns the path."""
    rows = []
    for m, (t, i) in enumerate(zip(np.asarray(times, float), np.asarray(played, int))):
        source = None if frames is None else frames[i]
        rows.append(side_by_side_frame(source, masks[i], expressive[i], shadows[m], f"{t:.2f}s #{i}", tile))
        report(progress, "video", m + 1, len(shadows))
    return write_video(path, rows, fps)
