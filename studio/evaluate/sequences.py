"""The sequences Table 2 runs on (DESIGN §4): each video file or frame folder loaded once, its frames sampled,
their expressive masks and keyframes computed (:func:`prepare_sequence`), so every row gets the same keyframe
targets in first-appearance order. Pure compute over :mod:`studio.targets`; :mod:`studio.evaluate.table2` runs the
rows on them.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from studio.errors import TargetError
from studio.motion.video_timing import video_end
from studio.targets.expressive import expressive_masks
from studio.targets.footage import VIDEO_SUFFIXES
from studio.targets.images import IMAGE_SUFFIXES
from studio.targets.keyframes import KeyframeConfig, cluster_keyframes, keyframe_targets
from studio.targets.path_checks import check_text, existing_paths
from studio.targets.video import VideoConfig, load_video


@dataclass
class PreparedSequence:
    """One sequence's keyframe targets, computed once for all rows (plain data)."""

    name: str  # shown in the tables (the file or folder name)
    source: Path  # the video file or frame folder
    times: np.ndarray  # (N,) s, source time of each sampled frame
    assignment: np.ndarray  # (N,) keyframe of each frame
    representatives: np.ndarray  # (K,) frame index of each keyframe, first-appearance order
    masks: np.ndarray  # (K, S, S) uint8 keyframe targets
    expressive: np.ndarray  # (K, S, S) uint8 their expressive masks (moving ∪ holes of the whole sequence)
    seconds: float  # loading, expressive masks and clustering
    end_s: float = 0.0  # the show's end on the video's clock (video_end; 0: the last frame's time + 1 s)

    @property
    def frames(self) -> int:
        return len(self.assignment)


def gather_sequences(paths: Sequence[str | Path]) -> list[Path]:
    """Sequence sources from the arguments: a video file; a folder of frames; or a folder of sequences (its
    frame sub-folders and video files, by name). A GIF in a folder is a video, not a frame. Raises
    :class:`TargetError` for a missing path or one holding no sequence."""
    videos = (*VIDEO_SUFFIXES, ".gif")
    frames = tuple(s for s in IMAGE_SUFFIXES if s != ".gif")

    def is_frame_folder(d: Path) -> bool:
        return any(f.is_file() and f.suffix.lower() in frames for f in d.iterdir())

    out: list[Path] = []
    for p in existing_paths(paths, "sequence (video file or frame folder)"):
        if p.is_file():
            out.append(p)
            continue
        if is_frame_folder(p):
            out.append(p)
            continue
        found = sorted(e for e in p.iterdir() if (e.is_file() and e.suffix.lower() in videos)
                       or (e.is_dir() and is_frame_folder(e)))  # fmt: skip
        if not found:
            raise TargetError(f"no sequences in {p}: no frames ({', '.join(frames)}), no frame sub-folders and no "
                              f"video files ({', '.join(videos)})")  # fmt: skip
        out += found
    check_text(out, "sequence name")  # named in the tables written at the end: refused now, not then
    return out


def prepare_sequence(
    path: Path, video_cfg: VideoConfig | None = None, keyframe_cfg: KeyframeConfig | None = None, name: str = ""
) -> PreparedSequence:
    """Load one sequence (errors: :func:`~studio.targets.video.load_video`), then :func:`sequence_from_masks`."""
    t0 = time.perf_counter()
    cfg = video_cfg or VideoConfig()
    video = load_video(path, replace(cfg, keep_frames=False))
    s = sequence_from_masks(video.masks, video.times, keyframe_cfg, name or Path(path).name, Path(path))
    s.end_s = video_end(s.times, cfg.hz, video.duration_s or None)
    s.seconds = time.perf_counter() - t0
    return s


def sequence_from_masks(
    masks: np.ndarray,
    times: np.ndarray | None = None,
    keyframe_cfg: KeyframeConfig | None = None,
    name: str = "sequence",
    source: Path | None = None,
) -> PreparedSequence:
    """Frames ``masks (N, S, S)`` uint8 (1 = shadow, one square frame) at ``times (N,)`` s (None: 0, 1, …) →
    their expressive masks and keyframes (:func:`~studio.targets.keyframes.cluster_keyframes`)."""
    t0 = time.perf_counter()
    masks = np.asarray(masks)
    expressive = expressive_masks(masks)
    clusters = cluster_keyframes(expressive, keyframe_cfg or KeyframeConfig(), masks)
    targets, exp = keyframe_targets(masks, expressive, clusters.representatives)
    times = np.arange(len(masks), dtype=float) if times is None else np.asarray(times, dtype=float)
    return PreparedSequence(name, Path(source or name), times, clusters.assignment, clusters.representatives,
                            targets, exp, time.perf_counter() - t0)  # fmt: skip
