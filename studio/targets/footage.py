"""Reading footage: a video file or a folder of frames → the RGB frames sampled at ``hz``, with their source times.

Sources (DESIGN §4 "Video targets"):

- a video file (:data:`VIDEO_SUFFIXES`, decoded by OpenCV's ``VideoCapture``) at its own constant rate; frame ``i``
  is at ``i / fps``;
- a GIF, decoded by Pillow with its real per-frame durations: frame ``i`` starts at the sum of the durations
  before it and the GIF's clock is the sum of all of them (a frame without a duration shows for 100 ms, as
  browsers do);
- a folder of image files (PNG, JPEG, …; sorted by name, numbers in names in numeric order) at ``fps`` (default
  24).

Sampling (:mod:`studio.targets.sampling`): sample ``k`` is the source frame whose start is nearest ``k / hz``. A
rate above the source's is an error saying the most it can be.

Bad input never ends in a traceback or a silently shorter show: a missing path, an unknown suffix, a file with no
readable frames, a GIF cut off in the middle, frames of mixed sizes in a folder, an empty folder each raise a
:class:`~studio.errors.TargetError` naming the file; a corrupt frame in the middle is skipped, counted in
``skipped`` and logged, and more than ``max_bad_share`` of the sampled frames bad is an error.
"""

from __future__ import annotations

import logging
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError

from studio.errors import ProgressFn, TargetError, report, stopped
from studio.targets.images import IMAGE_SUFFIXES
from studio.targets.sampling import gif_sample, sample_times

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".webm", ".mkv", ".m4v")  # decoded by OpenCV (FFmpeg)
GIF_DEFAULT_MS = 100.0  # shown duration of a GIF frame that gives none (or 0), as browsers do
FOLDER_FPS = 24.0  # the rate of a frame folder when none is given (DAVIS is 24 fps)


@dataclass
class Footage:
    """Sampled RGB frames of one source, before binarisation."""

    source: Path  # the file or folder read
    fps: float  # source frame rate (a GIF: its frames over its clock, the mean rate)
    hz: float  # sampling rate
    duration_s: float  # the source's clock: frames / fps, or a GIF's summed durations
    n_source: int  # frames in the source
    times: np.ndarray  # (N,) s, source time of each sampled frame read
    frame_index: np.ndarray  # (N,) int, its index in the source
    frames: np.ndarray  # (N, H, W, 3) uint8 RGB
    skipped: list[tuple[int, str]] = field(default_factory=list)  # (source index, reason) of sampled frames left out
    cancelled: bool = False  # the cancel event stopped reading: the arrays hold the frames read before it


def natural_key(path: Path) -> list:
    """Sort key that puts ``frame2`` before ``frame10``."""
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", path.name)]


def _rgb(im: Image.Image) -> np.ndarray:
    """A Pillow image as RGB ``(H, W, 3)`` uint8; a varying alpha channel is the shape (opaque = white), as
    :func:`~studio.targets.images.read_grey` reads stills; 16-bit and float images are stretched to 0-255."""
    if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
        alpha = np.asarray(im.convert("RGBA"))[..., 3]
        if alpha.min() < alpha.max():
            return np.repeat(alpha[..., None], 3, axis=2)
    if im.mode in ("I", "F") or im.mode.startswith("I;16"):
        a = np.asarray(im, dtype=np.float64)
        span = a.max() - a.min()
        g = np.zeros(a.shape, np.uint8) if span == 0 else ((a - a.min()) * (255 / span)).astype(np.uint8)
        return np.repeat(g[..., None], 3, axis=2)
    return np.asarray(im.convert("RGB")).copy()


def _check_rate(path: Path, fps: float, hz: float, what: str) -> None:
    if hz > fps * (1 + 1e-9):
        raise TargetError(
            f"sampling rate {hz:g} Hz is above the source's {what} {fps:g} fps: sample at {fps:g} Hz or less: {path}"
        )


def _check_bad(path: Path, skipped: list[tuple[int, str]], sampled: int, max_bad_share: float) -> None:
    if skipped:
        log.warning("%s: skipped %d of %d sampled frames: %s", path, len(skipped), sampled, skipped[:3])
    if sampled and len(skipped) > max_bad_share * sampled:
        first = "; ".join(f"frame {i}: {why}" for i, why in skipped[:3])
        raise TargetError(
            f"{len(skipped)} of {sampled} sampled frames are unreadable (more than {max_bad_share:.0%}): {first}: "
            f"{path}"
        )


def _tick(progress: ProgressFn | None, step: int, total: int) -> None:
    report(progress, "read", step, total)


def read_folder(
    folder: Path, fps: float, hz: float, max_bad_share: float, progress: ProgressFn | None, cancel
) -> Footage:
    """Sampled frames of a folder of image files at ``fps``."""
    files = sorted((p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES), key=natural_key)
    if not files:
        raise TargetError(f"frame folder holds no image files ({', '.join(IMAGE_SUFFIXES)}): {folder}")
    _check_rate(folder, fps, hz, "frame folder's rate")
    size, bad = None, {}
    for p in files:  # headers only: sizes must agree before any frame is used
        try:
            with Image.open(p) as im:
                turned = im.getexif().get(0x0112) in (5, 6, 7, 8)  # EXIF orientation: a quarter turn
                im_size = im.size[::-1] if turned else im.size
        except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as e:
            bad[p] = f"unreadable ({type(e).__name__}: {e})"
            continue
        if size is None:
            size, first = im_size, p
        elif im_size != size:
            raise TargetError(
                f"frames of mixed sizes: {p.name} is {im_size[0]}×{im_size[1]}, {first.name} is "
                f"{size[0]}×{size[1]}; every frame of a sequence must have one size: {folder}"
            )
    if size is None:
        raise TargetError(f"video has no readable frames: none of the {len(files)} image files opens: {folder}")
    times, idx = sample_times(len(files) / fps, fps, hz)
    frames, kept, skipped, cancelled = [], [], [], False
    for step, i in enumerate(idx):
        if stopped(cancel):
            cancelled = True
            break
        p = files[i]
        try:
            if p in bad:
                raise ValueError(bad[p])
            with Image.open(p) as im:
                im.load()
                frames.append(_rgb(ImageOps.exif_transpose(im)))
            kept.append(step)
        except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as e:
            skipped.append((int(i), f"{p.name} unreadable ({e})"))
        _tick(progress, step + 1, len(idx))
    _check_bad(folder, skipped, len(idx), max_bad_share)
    return _footage(folder, fps, hz, len(files) / fps, len(files), times[kept], idx[kept], frames, skipped, cancelled)


def read_gif(path: Path, hz: float, progress: ProgressFn | None, cancel) -> Footage:
    """Sampled frames of a GIF by its real per-frame durations (Pillow composes each frame onto the last). No frame
    is skipped: each is composed onto the last, so a bad one is an error (there is no share of bad frames to allow)."""
    try:
        im = Image.open(path)
    except (UnidentifiedImageError, OSError) as e:
        raise TargetError(f"unreadable GIF ({e}): {path}") from None
    with im:
        durations, composed = [], []
        try:
            for i in range(10**6):
                if stopped(cancel):  # the clock needs every frame: a cancelled GIF gives none
                    return _footage(path, 1.0, hz, 0.0, 0, [], np.zeros(0, np.int64), [], [], True)
                try:
                    im.seek(i)
                except EOFError:
                    break
                im.load()
                ms = im.info.get("duration") or 0
                durations.append(float(ms) if ms > 0 else GIF_DEFAULT_MS)
                composed.append(_rgb(im))  # every frame: the sample set needs the whole clock first
        except (OSError, ValueError, IndexError, SyntaxError) as e:
            raise TargetError(
                f"GIF cut off or corrupt at frame {len(durations)} ({e}): the frames after it and its length are "
                f"unknown; re-export the GIF: {path}"
            ) from None
    if not composed:
        raise TargetError(f"video has no readable frames: {path}")
    d = np.asarray(durations) / 1000.0
    duration_s = float(d.sum())
    fps = len(d) / duration_s
    _check_rate(path, fps, hz, "GIF's mean rate")
    times, idx = gif_sample(d, hz)
    _tick(progress, len(idx), len(idx))
    return _footage(path, fps, hz, duration_s, len(d), times, idx, [composed[i] for i in idx], [], False)


def read_video_file(path: Path, hz: float, max_bad_share: float, progress: ProgressFn | None, cancel) -> Footage:
    """Sampled frames of a video file through OpenCV at the file's own constant rate."""
    cap = cv2.VideoCapture(str(path))
    try:
        if not cap.isOpened():
            raise TargetError(f"video has no readable frames (cannot open it: truncated or not a video?): {path}")
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        if not fps > 0:
            raise TargetError(f"video gives no frame rate: {path}")
        _check_rate(path, fps, hz, "frame rate")
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if count <= 0:  # header without a frame count: count by decoding (rare: some streams)
            count = 0
            while cap.grab():
                count += 1
            cap.release()
            cap = cv2.VideoCapture(str(path))
        times, idx = sample_times(count / fps, fps, hz)
        want = {int(i): k for k, i in enumerate(idx)}
        frames, kept, skipped, cancelled = [], [], [], False
        decoded = fails = last_ok = 0
        for i in range(count):
            if fails >= 25:  # the stream has ended before its header's count
                break
            if stopped(cancel):
                cancelled = True
                break
            if not cap.grab():
                fails += 1
                if i in want:
                    skipped.append((i, "undecodable frame"))
                continue
            decoded, fails, last_ok = decoded + 1, 0, i
            if i in want:
                ok, bgr = cap.retrieve()
                if ok and bgr is not None and bgr.ndim == 3:
                    frames.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
                    kept.append(want[i])
                else:
                    skipped.append((i, "undecodable frame"))
                _tick(progress, want[i] + 1, len(idx))
    finally:
        cap.release()
    if decoded == 0:
        raise TargetError(f"video has no readable frames: {path}")
    if not cancelled:  # sampled frames after the last decoded one: the file ends early
        ends = f"missing: the file ends after {decoded} of the {count} frames its header gives (truncated?)"
        skipped = [(i, why) for i, why in skipped if i <= last_ok]
        skipped += [(int(i), ends) for i in idx if i > last_ok]
    _check_bad(path, skipped, len(idx), max_bad_share)
    return _footage(path, fps, hz, count / fps, count, times[kept], idx[kept], frames, skipped, cancelled)


def _footage(source, fps, hz, duration_s, n_source, times, idx, frames, skipped, cancelled) -> Footage:
    if not frames and not cancelled:
        raise TargetError(f"video has no readable frames: {source}")
    stack = np.stack(frames) if frames else np.zeros((0, 1, 1, 3), np.uint8)
    return Footage(source, fps, hz, duration_s, n_source, np.asarray(times, float), idx, stack, skipped, cancelled)


def read_footage(
    path: str | Path,
    hz: float,
    fps: float | None = None,
    max_bad_share: float = 0.25,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> Footage:
    """The frames of a video file, GIF or frame folder sampled at ``hz`` (module doc); ``fps`` is a folder's rate
    (default :data:`FOLDER_FPS`; a file's own rate is used otherwise). ``Progress("read", step, total)`` events."""
    path = Path(path)
    if not path.exists():
        raise TargetError(f"video not found: {path}")
    if path.is_dir():
        return read_folder(path, fps or FOLDER_FPS, hz, max_bad_share, progress, cancel)
    if fps is not None:
        log.info("fps %g ignored: %s plays at its own rate", fps, path.name)
    suffix = path.suffix.lower()
    if suffix == ".gif":
        return read_gif(path, hz, progress, cancel)
    if suffix in VIDEO_SUFFIXES:
        return read_video_file(path, hz, max_bad_share, progress, cancel)
    raise TargetError(
        f"unsupported video type {suffix or '(no suffix)'}: use a video file ({', '.join(VIDEO_SUFFIXES)}), "
        f"a GIF or a folder of frames: {path}"
    )
