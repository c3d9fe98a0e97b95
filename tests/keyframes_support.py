"""Clips the keyframe tests share (imported as ``from keyframes_support import ...``)."""

from __future__ import annotations

import cv2
import numpy as np


def ellipses(aspects, S: int = 64) -> np.ndarray:
    """One ellipse of constant area per aspect ratio (width / height), drifting down and right across the frame."""
    out = np.zeros((len(aspects), S, S), np.uint8)
    for i, r in enumerate(aspects):
        cv2.ellipse(out[i], (14 + 3 * i, 16 + 2 * i), (round(10 * r**0.5), round(10 / r**0.5)), 0, 0, 360, 1, -1)
    return out
