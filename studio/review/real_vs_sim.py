"""Real versus simulated: the shadow a camera saw beside the shadow the model casts (pure numpy + OpenCV).

:func:`overlay` draws a captured and a simulated shadow ``(R, R)`` (1 = shadow) in one tile so that where they differ
shows at a glance: both in shadow dark grey, only the camera's shadow orange, only the simulation's blue, both lit
the backdrop's light grey. :func:`compare_sheet` lays out one row per pose (the rig calibration's picture):
photograph | captured | simulated before | after, the overlays labelled with their window IoU losses.
:func:`real_sim_row` is one keyframe's row for a show played with a camera: target | captured | simulated |
overlay, labelled with the losses; :func:`real_sim_sheet` stacks them (``real_vs_sim.png``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import cv2
import numpy as np

from studio.review.sheets import BACKDROP, GAP, SHADOW, fit_tile, grid, label, shadow_tile

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


def _loss_text(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.3f}"


def _blank(tile: int, text: str) -> np.ndarray:
    return label(np.full((tile, tile, 3), GAP, np.uint8), text)


def real_sim_row(
    target: np.ndarray | None,
    captured: np.ndarray | None,
    simulated: np.ndarray,
    tile: int = 192,
    losses: Mapping[str, float] | None = None,
    name: str = "",
) -> np.ndarray:
    """One keyframe of a show played with a camera: its target | the camera's shadow | the simulated shadow |
    overlay of captured and simulated (the module's colours) → RGB ``(T, 4T + 3 gaps, 3)`` uint8.

    ``target`` ``(S, S)``, ``captured`` and ``simulated`` ``(R, R)``, 1 = shadow; a missing target or picture is a
    grey tile saying so. ``losses`` (``captured_vs_target``, ``simulated_vs_target``, ``captured_vs_simulated``;
    NaN: not computed, shown as ``-``) label the tiles; without them the window IoU losses are computed here.
    ``name`` is written on the first tile (``"k2 1.50 s"``)."""
    simulated = np.asarray(simulated)
    if losses is None:
        t = None if target is None else cv2.resize(np.asarray(target, np.uint8), simulated.shape[::-1],
                                                    interpolation=cv2.INTER_NEAREST)  # fmt: skip
        both = (t is not None) and (captured is not None)
        losses = {
            "captured_vs_target": window_iou_loss(t, captured) if both else math.nan,
            "simulated_vs_target": window_iou_loss(t, simulated) if t is not None else math.nan,
            "captured_vs_simulated": window_iou_loss(captured, simulated) if captured is not None else math.nan,
        }
    head = f"{name} " if name else ""
    real_sim = f"real vs sim {_loss_text(losses.get('captured_vs_simulated'))}"
    cells = [
        _blank(tile, f"{head}no target") if target is None else label(shadow_tile(target, tile), f"{head}target"),
        _blank(tile, "no picture")
        if captured is None
        else label(shadow_tile(captured, tile), f"captured {_loss_text(losses.get('captured_vs_target'))}"),
        label(shadow_tile(simulated, tile), f"simulated {_loss_text(losses.get('simulated_vs_target'))}"),
        _blank(tile, "real vs sim -") if captured is None else label(overlay(captured, simulated, tile), real_sim),
    ]
    return grid([cells], gap=4)


def real_sim_sheet(rows: Sequence[np.ndarray]) -> np.ndarray:
    """Rows of :func:`real_sim_row` one under the other → RGB ``(H, W, 3)`` uint8 (``write_png`` writes it)."""
    return grid([[r] for r in rows], gap=6)
