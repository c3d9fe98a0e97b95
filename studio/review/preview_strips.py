"""The pictures around the show preview (pure numpy + OpenCV): the timeline under the player and the frame strip.

- :func:`timeline_image`: the show clock left to right: a tick where each keyframe's pose is reached, coloured by
  its result's status (:data:`STATUS_RGB`: missing red, stale amber, current green), late (stretched) transitions
  shaded red, the move from home shaded blue-grey. :func:`timeline_x` is where a time falls on it.
- :func:`strip_image`: every sampled frame as a ``target | shadow`` cell labelled with its frame number and its
  keyframe's loss (:func:`~studio.review.sheets.pair_sheet`, the cells of ``contact.png``: the shadow is the pose
  the frame's keyframe plays, blank until it has a current result), with each cell's box, so a click at a pixel
  names its frame (:func:`cell_at`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from studio.review.preview import PreviewClock
from studio.review.sheets import pair_sheet

STATUS_RGB = {"missing": (215, 48, 39), "stale": (245, 166, 35), "current": (46, 160, 67)}  # keyframe tick colours
LATE_RGB = (250, 200, 200)  # shading of a late transition
HOME_RGB = (214, 220, 236)  # shading of the move from home
TIMELINE_RGB = (248, 248, 248)  # the timeline's background
TICK_PX = 3  # width of a keyframe tick, px
STRIP_GAP, PAIR_GAP = 6, 2  # px between cells, and between a cell's target and shadow (pair_sheet's layout)


def timeline_x(t: float | np.ndarray, start: float, end: float, width: int) -> np.ndarray:
    """Column ``[0, width)`` of show time ``t`` on a timeline from ``start`` to ``end`` s, ``width`` px wide."""
    span = max(end - start, 1e-9)
    return np.clip(np.round((np.asarray(t, float) - start) / span * (width - 1)), 0, width - 1).astype(int)


def timeline_image(clock: PreviewClock, width: int = 640, height: int = 24) -> np.ndarray:
    """The timeline of ``clock`` (module doc) → RGB ``(height, width, 3)`` uint8."""
    img = np.empty((height, width, 3), np.uint8)
    img[:] = TIMELINE_RGB

    def span(a: float, b: float, rgb: tuple[int, int, int]) -> None:
        x0, x1 = timeline_x([a, b], clock.start, clock.end, width)
        img[:, x0 : x1 + 1] = rgb

    if clock.start < 0:
        span(clock.start, 0.0, HOME_RGB)
    for a, b in clock.late:
        span(a, b, LATE_RGB)
    img[height // 2] = (170, 170, 170)  # the time axis
    half = TICK_PX // 2
    for tick in clock.ticks:
        x = int(timeline_x(tick.t, clock.start, clock.end, width))
        img[:, max(0, x - half) : x + half + 1] = STATUS_RGB[tick.status]
    return img


def cell_boxes(n: int, tile: int, columns: int) -> list[tuple[int, int, int, int]]:
    """``(x, y, w, h)`` px of each of ``n`` cells of :func:`strip_image` (``columns`` a row)."""
    w, h = 2 * tile + PAIR_GAP, tile
    return [((i % columns) * (w + STRIP_GAP), (i // columns) * (h + STRIP_GAP), w, h) for i in range(n)]


def cell_at(boxes: Sequence[Sequence[int]], x: float, y: float) -> int | None:
    """The cell whose box holds pixel ``(x, y)`` (None: a gap or outside)."""
    for i, (bx, by, bw, bh) in enumerate(boxes):
        if bx <= x < bx + bw and by <= y < by + bh:
            return i
    return None


def strip_image(
    targets: np.ndarray, expressive: np.ndarray, shadows: Sequence[np.ndarray], labels: Sequence[str], tile: int = 64,
    columns: int = 8,
) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:  # fmt: skip
    """Frames ``targets``/``expressive`` ``(N, S, S)`` each beside ``shadows[i]`` (the pose its keyframe plays;
    blank for none) and labelled ``labels[i]`` (module doc) → (RGB ``(H, W, 3)`` uint8, each frame's cell box
    ``(x, y, w, h)`` px)."""
    n = len(targets)
    columns = max(1, min(columns, n))
    img = pair_sheet(targets, expressive, list(shadows), list(labels), tile=tile, columns=columns)
    return img, cell_boxes(n, tile, columns)
