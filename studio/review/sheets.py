"""Contact sheets: grids of mask tiles a person scans at a glance, written as PNG (pure numpy + OpenCV).

Tiles follow the display convention of the rest of the studio (dark shadow on a light backdrop) and are RGB
``(T, T, 3)`` uint8. :func:`grid` lays out rows of tiles; :func:`keyframe_sheet` shows a sequence's keyframe
clusters, one cluster per row (wrapped after ``columns`` tiles) with its representative first and framed, each tile
the frame's mask with its expressive region tinted and labelled with its frame index (and time);
:func:`pair_sheet` shows every frame of a sequence as ``target | shadow``; :func:`side_by_side` and
:func:`write_video` make side-by-side review videos (OpenCV's ``VideoWriter``, MPEG-4).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from studio.atomic import write_bytes, write_via

BACKDROP = (235, 235, 235)  # RGB of the lit backdrop
SHADOW = (40, 40, 40)  # RGB of plain shadow
EXPRESSIVE_SHADOW = (200, 60, 30)  # RGB of shadow that is expressive (it moves)
EXPRESSIVE_BACKDROP = (250, 180, 120)  # RGB of backdrop that is expressive (a hole)
REPRESENTATIVE = (30, 140, 230)  # RGB frame around a cluster's representative
GAP = 128  # grey between tiles


def display(mask: np.ndarray) -> np.ndarray:
    """Shadow probabilities/mask ``(H, W)`` (1 = shadow) → uint8 image, dark shadow on a light backdrop."""
    return (255 * (1.0 - np.clip(np.asarray(mask, dtype=float), 0, 1))).astype(np.uint8)


def tint(mask: np.ndarray, expressive: np.ndarray | None = None, tile: int | None = None) -> np.ndarray:
    """Mask ``(S, S)`` (1 = shadow) with its expressive region ``(S, S)`` tinted → RGB ``(T, T, 3)`` uint8.

    ``tile`` resizes to ``T × T`` (nearest, so thin parts stay visible); None keeps ``S``.
    """
    shadow = np.asarray(mask) != 0
    expr = np.zeros_like(shadow) if expressive is None else np.asarray(expressive) != 0
    img = np.empty(shadow.shape + (3,), np.uint8)
    img[:] = BACKDROP
    img[shadow] = SHADOW
    img[expr & shadow] = EXPRESSIVE_SHADOW
    img[expr & ~shadow] = EXPRESSIVE_BACKDROP
    if tile is not None and tile != img.shape[0]:
        img = cv2.resize(img, (tile, tile), interpolation=cv2.INTER_NEAREST)
    return img


def label(img: np.ndarray, text: str) -> np.ndarray:
    """``img`` ``(T, T, 3)`` with ``text`` written small in its top-left corner (a copy)."""
    out = img.copy()
    scale = max(0.3, out.shape[0] / 256)
    org = (3, int(12 * scale / 0.4))
    cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 3, cv2.LINE_AA)
    cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), 1, cv2.LINE_AA)
    return out


def frame_border(img: np.ndarray, color: tuple[int, int, int] = REPRESENTATIVE, width: int = 3) -> np.ndarray:
    """``img`` ``(T, T, 3)`` with a ``width``-pixel border of ``color`` (a copy)."""
    out = img.copy()
    out[:width], out[-width:], out[:, :width], out[:, -width:] = color, color, color, color
    return out


def grid(rows: Sequence[Sequence[np.ndarray]], gap: int = 4) -> np.ndarray:
    """Rows of equal-size RGB tiles ``(T, T', 3)`` → one RGB image; short rows are padded with the gap grey."""
    rows = [list(r) for r in rows if len(r)]
    if not rows:
        raise ValueError("a contact sheet needs at least one tile")
    h, w = rows[0][0].shape[:2]
    if any(t.shape[:2] != (h, w) for r in rows for t in r):
        raise ValueError("every tile of a contact sheet must have the same size")
    cols = max(len(r) for r in rows)
    out = np.full((len(rows) * (h + gap) - gap, cols * (w + gap) - gap, 3), GAP, np.uint8)
    for i, r in enumerate(rows):
        for j, t in enumerate(r):
            out[i * (h + gap) : i * (h + gap) + h, j * (w + gap) : j * (w + gap) + w] = t
    return out


def keyframe_sheet(
    masks: np.ndarray,
    expressive: np.ndarray,
    members: Sequence[Sequence[int]],
    representatives: Sequence[int],
    times: np.ndarray | None = None,
    tile: int = 96,
    columns: int = 16,
) -> np.ndarray:
    """The clusters of a sequence as RGB ``(H, W, 3)`` uint8: one row per cluster (wrapped after ``columns``),
    representative first and framed, then the other members in frame order.

    ``masks`` and ``expressive`` are ``(N, S, S)``; ``members[k]`` are cluster k's frame indices and
    ``representatives[k]`` its keyframe; ``times (N,)`` s, when given, label each tile next to its frame index.
    """
    if len(members) != len(representatives):
        raise ValueError(f"{len(members)} clusters but {len(representatives)} representatives")
    if columns < 1:
        raise ValueError("columns must be at least 1")
    rows: list[list[np.ndarray]] = []
    for k, (group, rep) in enumerate(zip(members, representatives, strict=True)):
        order = [int(rep)] + [int(i) for i in group if i != rep]
        tiles = []
        for i in order:
            text = f"k{k} #{i}" if i == rep else f"#{i}"
            if times is not None:
                text += f" {float(times[i]):.2f}s"
            t = label(tint(masks[i], expressive[i], tile), text)
            tiles.append(frame_border(t) if i == rep else t)
        rows += [tiles[j : j + columns] for j in range(0, len(tiles), columns)]
    return grid(rows)


def shadow_tile(mask: np.ndarray, tile: int) -> np.ndarray:
    """A plain shadow ``(R, R)`` (1 = shadow, e.g. a rendered one) → RGB ``(T, T, 3)`` uint8 tile (no tint)."""
    return tint(mask, None, tile)


def pair_sheet(
    targets: np.ndarray,
    expressive: np.ndarray,
    shadows: Sequence[np.ndarray],
    labels: Sequence[str],
    tile: int = 96,
    columns: int = 6,
) -> np.ndarray:
    """A sequence's frames as RGB ``(H, W, 3)`` uint8 cells of ``target | shadow``, ``columns`` cells a row.

    ``targets`` and ``expressive`` are ``(N, S, S)`` (the target tinted with its expressive region), ``shadows``
    N shadows ``(R, R)`` (1 = shadow; a frame's keyframe shadow), ``labels`` N texts written on the targets."""
    if not len(targets) == len(expressive) == len(shadows) == len(labels):
        raise ValueError("a pair sheet needs one expressive mask, shadow and label per target")
    if columns < 1:
        raise ValueError("columns must be at least 1")
    gap = np.full((tile, 2, 3), GAP, np.uint8)
    cells = [
        np.concatenate([label(tint(t, e, tile), text), gap, shadow_tile(s, tile)], axis=1)
        for t, e, s, text in zip(targets, expressive, shadows, labels)
    ]
    return grid([cells[j : j + columns] for j in range(0, len(cells), columns)], gap=6)


def fit_tile(rgb: np.ndarray, tile: int) -> np.ndarray:
    """An RGB ``(H, W, 3)`` image resized to fit a ``tile × tile`` square (area averaging), padded with the gap
    grey → ``(T, T, 3)`` uint8."""
    h, w = rgb.shape[:2]
    scale = tile / max(h, w)
    nh, nw = max(1, round(h * scale)), max(1, round(w * scale))
    small = cv2.resize(np.ascontiguousarray(rgb), (nw, nh), interpolation=cv2.INTER_AREA)
    out = np.full((tile, tile, 3), GAP, np.uint8)
    r0, c0 = (tile - nh) // 2, (tile - nw) // 2
    out[r0 : r0 + nh, c0 : c0 + nw] = small
    return out


def side_by_side(panels: Sequence[np.ndarray], tile: int = 192) -> np.ndarray:
    """RGB panels (each ``(H, W, 3)`` uint8) fitted to ``tile × tile`` squares side by side → ``(T, W', 3)``."""
    gap = np.full((tile, 4, 3), GAP, np.uint8)
    row = [x for p in panels for x in (fit_tile(p, tile), gap)][:-1]
    return np.concatenate(row, axis=1)


VIDEO_CODEC = "mp4v"  # MPEG-4 part 2: encodes in opencv-python-headless's bundled FFmpeg (H.264 'avc1' does not)


def write_video(path: str | Path, frames_rgb: Sequence[np.ndarray], fps: float, codec: str = VIDEO_CODEC) -> Path:
    """Write RGB frames ``(H, W, 3)`` uint8 (all one size) as a video at ``fps``; returns the path.

    Written atomically (:func:`studio.atomic.write_via`: into a private temporary folder beside ``path``, whose
    random name nobody can plant a symlink at, then renamed: a video is never half-written). Odd sides are padded to
    even ones (MPEG-4 wants even sides). Raises ``OSError`` when no encoder opens."""
    path = Path(path)
    if not len(frames_rgb):
        raise ValueError("a video needs at least one frame")
    h, w = frames_rgb[0].shape[:2]
    H, W = h + h % 2, w + w % 2

    def encode(tmp: Path) -> None:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*codec), float(fps), (W, H))
        if not writer.isOpened():
            raise OSError(f"OpenCV could not open a {codec!r} video encoder for {path}")
        try:
            for f in frames_rgb:
                if f.shape[:2] != (h, w):
                    raise ValueError(f"every video frame must be {h}×{w}, got {f.shape[:2]}")
                frame = np.full((H, W, 3), GAP, np.uint8)
                frame[:h, :w] = f
                writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        finally:
            writer.release()

    return write_via(path, encode)


def write_png(path: str | Path, rgb: np.ndarray) -> Path:
    """Write an RGB ``(H, W, 3)`` uint8 image as PNG, atomically; returns the path."""
    ok, png = cv2.imencode(".png", cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR))
    if not ok:
        raise OSError(f"could not encode {path} as PNG")
    return write_bytes(path, png.tobytes())
