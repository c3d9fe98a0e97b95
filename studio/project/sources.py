"""A project's sources: content hashes, finding a moved source, and loading sources into frames and masks.

A source is a still (an image file; a one-frame GIF), a video (a video file or an animated GIF) or a folder of
frames. Its content hash is the sha256 of the file, or for a folder of its sorted file names and their contents, so
a changed source is told apart from a moved one. Loading goes through the one reader every face uses,
:func:`~studio.targets.source.open_source` (stills framed at the project's size, colour footage segmented densely
from its first-frame box or mask). Expressive masks are computed per source (what moves within that source, plus
holes): a still's is its holes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from studio.errors import ProgressFn, StudioError
from studio.project.containment import check_source_path, is_source_path
from studio.project.state import Frame, Source
from studio.project.status import MissingSource
from studio.targets.expressive import expressive_masks
from studio.targets.images import TargetConfig
from studio.targets.source import open_source, source_kind
from studio.targets.video import VideoConfig

log = logging.getLogger(__name__)

_CHUNK = 1 << 20


def _hash_file(h: hashlib._Hash, path: Path) -> None:
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            h.update(chunk)


def hash_source(path: str | Path) -> str:
    """sha256 (hex) of a source: a file's bytes, or a folder's files (directly inside) by sorted name + content."""
    path = Path(path)
    h = hashlib.sha256()
    if path.is_dir():
        for p in sorted((p for p in path.iterdir() if p.is_file()), key=lambda p: p.name):
            h.update(p.name.encode("utf-8", "surrogateescape") + b"\0")
            h.update(str(p.stat().st_size).encode() + b"\0")
            _hash_file(h, p)
    else:
        _hash_file(h, path)
    return h.hexdigest()


def make_source(path: str | Path) -> Source:
    """A new :class:`Source` for ``path`` (as given), hashed; a ProjectError when it does not exist."""
    p = check_source_path(Path(path).expanduser(), path)
    return Source(path=str(path), absolute=str(p.resolve()), sha256=hash_source(p), kind=source_kind(p))


def locate(src: Source, folder: Path) -> Path | None:
    """Where ``src`` is now: its absolute path, else its path as given (from here, or beside the project folder
    ``folder`` when relative); None when it is in none of them (moved or deleted)."""
    given = Path(src.path).expanduser()
    candidates = [Path(src.absolute), given]
    if not given.is_absolute():
        candidates.append(Path(folder).resolve().parent / given)
    return next((c for c in candidates if is_source_path(c)), None)


def load_source(
    index: int, src: Source, path: Path, video: VideoConfig, still: TargetConfig, progress: ProgressFn | None = None
) -> tuple[Source, list[Frame], np.ndarray]:
    """Read source number ``index`` from ``path``: the source updated with what loading found (hash, absolute
    path, rate, frame), its frames and their masks ``(n, S, S)`` uint8, S = ``video.size``. Colour footage without
    a first-frame box or mask raises :class:`~studio.targets.video.SegmentationNeeded`."""
    src = dataclasses.replace(src, absolute=str(path.resolve()), sha256=hash_source(path), kind=source_kind(path))
    box, first_mask = (None, None) if src.kind == "still" else (src.box, src.first_mask)
    v = open_source(path, dataclasses.replace(video, keep_frames=False), still, box, first_mask, progress)
    if src.kind == "still":
        return dataclasses.replace(src, footage="still"), [Frame(index, 0, 0.0)], v.masks
    frames = [Frame(index, int(i), float(t)) for i, t in zip(v.frame_index, v.times, strict=True)]
    found = dataclasses.replace(
        src, footage=v.kind, fps=float(v.fps), duration_s=float(v.duration_s), n_source=int(v.n_source),
        frame_box=tuple(int(x) for x in v.box),
    )  # fmt: skip
    return found, frames, v.masks


def load_sources(
    sources: Sequence[Source],
    paths: Sequence[Path],
    video: VideoConfig,
    still: TargetConfig,
    progress: ProgressFn | None = None,
) -> tuple[tuple[Source, ...], tuple[Frame, ...], np.ndarray, np.ndarray]:
    """Every source read from ``paths``: ``(sources updated, frames, targets (N, S, S), auto expressive (N, S, S))``,
    the expressive masks computed within each source (module doc)."""
    out_sources, frames, targets, auto = [], [], [], []
    for i, (src, path) in enumerate(zip(sources, paths, strict=True)):
        found, fr, masks = load_source(i, src, Path(path), video, still, progress)
        out_sources.append(found)
        frames.extend(fr)
        targets.append(masks.astype(np.uint8))
        auto.append(expressive_masks(masks))
        log.info("source %d (%s): %d frames", i, src.path, len(fr))
    return tuple(out_sources), tuple(frames), np.concatenate(targets), np.concatenate(auto)


def framed_frames(sources: Sequence[Source], frames: Sequence[Frame], folder: Path, video: VideoConfig) -> list:
    """Every project frame's RGB source image framed like its target, ``(S, S, 3)`` uint8 (S = ``video.size``), for
    review; None for a still's frame and for a source that is missing or can no longer be read."""
    from studio.targets.images import crop_square
    from studio.targets.source import raw_frames

    out: list = [None] * len(frames)
    for i, src in enumerate(sources):
        where = locate(src, folder)
        mine = [n for n, f in enumerate(frames) if f.source == i]
        if src.kind == "still" or where is None or src.frame_box is None or not mine:
            continue
        try:
            footage = raw_frames(where, video)
        except StudioError as e:
            log.warning("source %d (%s): its frames cannot be read for review: %s", i, src.path, e)
            continue
        by_index = {int(j): k for k, j in enumerate(footage.frame_index)}
        for n in mine:
            k = by_index.get(frames[n].source_frame)
            if k is not None:
                framed = crop_square(footage.frames[k], src.frame_box, video.size)
                out[n] = np.clip(framed + 0.5, 0, 255).astype(np.uint8)
    return out


def check_sources(sources: Sequence[Source], project: Path) -> tuple[list[MissingSource], list[int]]:
    """The sources of the project at ``project`` that are missing (where they were last read, with a warning each)
    and the indices of those whose content changed since (their results are stale)."""
    missing, changed = [], []
    for i, src in enumerate(sources):
        where = locate(src, project)
        if where is None:
            missing.append(MissingSource(i, src.path, src.absolute))
            log.warning(
                "%s: source %d is missing: it was at %s (given as %s); its frames and results are kept, and "
                "re-reading it needs it relinked (source %d)", project, i, src.absolute, src.path, i
            )  # fmt: skip
        elif hash_source(where) != src.sha256:
            changed.append(i)
            log.warning("%s: source %d changed since it was read (%s): its results are stale", project, i, where)
    return missing, changed
