"""Real versus simulated: the shadow a camera saw beside the shadow the model casts (pure numpy + OpenCV).

:func:`overlay` draws a captured and a simulated shadow ``(R, R)`` (1 = shadow) in one tile so that where they differ
shows at a glance: both in shadow dark grey, only the camera's shadow orange, only the simulation's blue, both lit
the backdrop's light grey. :func:`compare_sheet` lays out one row per pose (the rig calibration's picture):
photograph | captured | simulated before | after, the overlays labelled with their window IoU losses.
:func:`real_sim_row` is one keyframe's row for a show played with a camera: target | captured | simulated.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from studio.review.sheets import BACKDROP, SHADOW, fit_tile, grid, label, shadow_tile

ONLY_REAL = (235, 140, 40)  # RGB where only the camera saw shadow
ONLY_SIM = (60, 120, 230)  # RGB where only the simulation casts shadow


def window_iou_loss(a: np.ndarray, b: np.ndarray) -> float:
    """``1 - IoU`` of two binary ``(R, R)`` shadows (0 when both are empty)."""
    a, b = np.asarray(a) != 0, np.asarray(b) != 0
    union = int((a | b).sum())
    return 0.0 if union == 0 else 1.0 - int((a & b).sum()) / union


def overlay(captured: np.ndarray, simulated: np.ndarray, tile: int | None = None) -> np.ndarray:
    """Captured and simulated shadows ``(R, R)`` → RGB ``(T, T, 3)`` uint8 (see the module's colours)."""
    real, sim = np.asarray(captured) != 0, np.asarray(simulated) != 0
    img = np.empty(real.shape + (3,), np.uint8)
    img[:] = BACKDROP
    img[real & sim] = SHADOW
    img[real & ~sim] = ONLY_REAL
    img[~real & sim] = ONLY_SIM
    if tile is not None and tile != img.shape[0]:
        img = cv2.resize(img, (tile, tile), interpolation=cv2.INTER_AREA)
    return img


def compare_sheet(
    photos: Sequence[np.ndarray],
    captured: np.ndarray,
    before: np.ndarray,
    after: np.ndarray,
    tile: int = 160,
) -> np.ndarray:
    """One row per pose: the photograph (BGR as the camera gives it) | captured | overlay with the rig before |
    overlay with the rig after, the overlays labelled with their losses → a BGR image (for ``cv2.imencode``)."""
    rows = []
    for i in range(len(captured)):
        photo = fit_tile(cv2.cvtColor(photos[i], cv2.COLOR_BGR2RGB), tile) if i < len(photos) else None
        cells = [] if photo is None else [label(photo, f"pose {i + 1}")]
        cells += [
            label(shadow_tile(captured[i], tile), "captured"),
            label(overlay(captured[i], before[i], tile), f"before {window_iou_loss(captured[i], before[i]):.3f}"),
            label(overlay(captured[i], after[i], tile), f"after {window_iou_loss(captured[i], after[i]):.3f}"),
        ]
        rows.append(cells)
    return cv2.cvtColor(grid(rows, gap=4), cv2.COLOR_RGB2BGR)


def real_sim_row(target: np.ndarray, captured: np.ndarray, simulated: np.ndarray, tile: int = 192) -> np.ndarray:
    """One keyframe: its target | the camera's shadow | overlay of captured and simulated, with the losses of the
    captured and the simulated shadow against the target → RGB ``(T, 3T + gaps, 3)`` uint8."""
    t = cv2.resize(np.asarray(target, np.uint8), captured.shape[::-1], interpolation=cv2.INTER_NEAREST)
    cells = [
        label(shadow_tile(t, tile), "target"),
        label(shadow_tile(captured, tile), f"captured {window_iou_loss(t, captured):.3f}"),
        label(overlay(captured, simulated, tile), f"simulated {window_iou_loss(t, simulated):.3f}"),
    ]
    return grid([cells], gap=4)
