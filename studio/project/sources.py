"""A project's sources: content hashes, finding a moved source, and loading sources into frames and masks.

A source is a still (an image file; a one-frame GIF), a video (a video file or an animated GIF) or a folder of
frames. Its content hash is the sha256 of the file, or for a folder of its sorted file names and their contents, so
a changed source is told apart from a moved one. Loading goes through the engine's loaders: stills through
:func:`~studio.targets.images.load_target` (framed at the project's size), videos through
:func:`~studio.targets.video.load_video`, colour footage segmented from its first-frame box or mask
(:mod:`studio.targets.segment`). Expressive masks are computed per source (what moves within that source, plus
holes): a still's is its holes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from studio.project.state import Frame, ProjectError, Source
from studio.targets.expressive import expressive_masks
from studio.targets.images import IMAGE_SUFFIXES, TargetConfig, load_target
from studio.targets.video import SegmentationNeeded, VideoConfig, load_video, video_from_masks

log = logging.getLogger(__name__)

Progress = Callable[[str, int, int], None]  # progress(stage, step, total)
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


def source_kind(path: str | Path) -> str:
    """``"folder"``, ``"still"`` (an image file with one frame) or ``"video"`` (anything else: a video file, an
    animated GIF or WebP)."""
    path = Path(path)
    if path.is_dir():
        return "folder"
    if path.suffix.lower() in IMAGE_SUFFIXES:
        try:
            with Image.open(path) as im:
                return "still" if getattr(im, "n_frames", 1) == 1 else "video"
        except OSError:
            return "still"  # load_target says what is wrong with it
    return "video"


def make_source(path: str | Path) -> Source:
    """A new :class:`Source` for ``path`` (as given), hashed; a ProjectError when it does not exist."""
    p = Path(path).expanduser()
    if not p.exists():
        raise ProjectError(f"source not found: {path}")
    return Source(path=str(path), absolute=str(p.resolve()), sha256=hash_source(p), kind=source_kind(p))


def locate(src: Source, folder: Path) -> Path | None:
    """Where ``src`` is now: its absolute path, else its path as given (from here, or beside the project folder
    ``folder`` when relative); None when it is in none of them (moved or deleted)."""
    given = Path(src.path).expanduser()
    candidates = [Path(src.absolute), given]
    if not given.is_absolute():
        candidates.append(Path(folder).resolve().parent / given)
    return next((c for c in candidates if c.exists()), None)


def _load_video(src: Source, path: Path, cfg: VideoConfig, progress: Progress | None):
    try:
        return load_video(path, cfg, progress)
    except SegmentationNeeded as e:
        if src.box is None and src.first_mask is None:
            raise ProjectError(
                f"{path.name} is colour footage: the object must be segmented first; give its first-frame box or "
                "mask (project new --box x,y,w,h or --first-mask PNG; Project.set_segmentation)"
            ) from None
        from studio.targets.segment import segment_video

        seg = (lambda s, i, n: progress(s, i, n)) if progress else None
        masks = segment_video(e.footage.frames, box=src.box, first_mask=src.first_mask, progress=seg)
        return video_from_masks(e.footage, masks, cfg, progress=progress)


def load_source(
    index: int, src: Source, path: Path, video: VideoConfig, still: TargetConfig, progress: Progress | None = None
) -> tuple[Source, list[Frame], np.ndarray]:
    """Read source number ``index`` from ``path``: the source updated with what loading found (hash, absolute
    path, rate, frame), its frames and their masks ``(n, S, S)`` uint8, S = ``video.size``."""
    src = dataclasses.replace(src, absolute=str(path.resolve()), sha256=hash_source(path), kind=source_kind(path))
    if src.kind == "still":
        mask = load_target(path, size=video.size, cfg=still)
        return dataclasses.replace(src, footage="still"), [Frame(index, 0, 0.0)], mask[None]
    v = _load_video(src, path, dataclasses.replace(video, keep_frames=False), progress)
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
    progress: Progress | None = None,
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
