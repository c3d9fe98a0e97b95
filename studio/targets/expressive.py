"""Expressive regions of a mask sequence: what moves, plus every hole (DESIGN §4); a still's: its holes.

Frame i's expressive region is its shadow minus the pixels that are shadow in *every* frame of the sequence (the
static body: :func:`moving_region`), plus its holes (connected components of the inverted mask that do not touch
the border, 4-connected: :func:`holes_region`). The expressive loss then weighs what makes the frame readable —
a wing that flaps, a mouth that opens — over the bulk every frame shares.

An artist's painted corrections are kept apart from the automatic mask and combined with it, never replacing it
(:func:`combine`): ``(auto | additions) & ~erasures``. Re-running the automatic step after a change in the source
or the sampling keeps the strokes.

All masks are uint8, 1 = shadow (or = expressive), in one square frame: ``(N, S, S)`` for a sequence, ``(S, S)``
for one frame.
"""

from __future__ import annotations

import numpy as np

from studio.targets.holes import find_holes


def _check_sequence(masks: np.ndarray) -> np.ndarray:
    masks = np.asarray(masks)
    if masks.ndim != 3 or masks.shape[0] == 0:
        raise ValueError(f"masks must be a non-empty sequence (N, S, S), not an array of shape {masks.shape}")
    return masks != 0


def moving_region(masks: np.ndarray) -> np.ndarray:
    """Masks ``(N, S, S)`` → each frame's shadow minus the pixels that are shadow in every frame, ``(N, S, S)``
    uint8. A single frame has no motion: its moving region is empty."""
    shadow = _check_sequence(masks)
    static = shadow.all(axis=0)
    return (shadow & ~static).astype(np.uint8)


def holes_region(masks: np.ndarray) -> np.ndarray:
    """Masks ``(N, S, S)`` → each frame's holes (backdrop not 4-connected to the border), ``(N, S, S)`` uint8."""
    shadow = _check_sequence(masks)
    return np.stack([find_holes(m.astype(np.uint8)) for m in shadow])


def expressive_masks(masks: np.ndarray) -> np.ndarray:
    """Masks ``(N, S, S)`` uint8 (1 = shadow) → automatic expressive masks ``(N, S, S)`` uint8: moving ∪ holes."""
    return moving_region(masks) | holes_region(masks)


def combine(auto: np.ndarray, additions: np.ndarray | None = None, erasures: np.ndarray | None = None) -> np.ndarray:
    """The expressive mask an artist sees: ``(auto | additions) & ~erasures``, uint8 of ``auto``'s shape.

    ``auto`` is ``(N, S, S)`` or ``(S, S)``; ``additions`` and ``erasures`` (painted, nonzero = painted) have the
    same shape, or are one ``(S, S)`` stroke layer applied to every frame; None = nothing painted. The inputs are
    left untouched, so the automatic mask can be recomputed and combined again with the same strokes.
    """
    auto = np.asarray(auto)
    if auto.ndim not in (2, 3):
        raise ValueError(f"auto must be (S, S) or (N, S, S), not an array of shape {auto.shape}")
    out = auto != 0
    for name, layer in (("additions", additions), ("erasures", erasures)):
        if layer is None:
            continue
        layer = np.asarray(layer)
        if layer.shape != auto.shape and layer.shape != auto.shape[-2:]:
            raise ValueError(f"{name} of shape {layer.shape} do not fit the expressive masks of shape {auto.shape}")
        out = out | (layer != 0) if name == "additions" else out & ~(layer != 0)
    return out.astype(np.uint8)


def still_expressive(target: np.ndarray) -> np.ndarray | None:
    """The expressive region of a still target ``(S, S)``: its holes (openings), or None when it has none."""
    holes = find_holes(target)
    return holes if holes.any() else None
