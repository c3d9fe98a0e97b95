"""What a :class:`hardware.camera.Camera` reads besides a video file: a device opened quietly, a folder of frames
played as a camera, and any source's picture as BGR."""

from __future__ import annotations

import logging
import re
from pathlib import Path
from typing import Any

import cv2
import numpy as np

__all__ = ["FRAME_SUFFIXES", "FolderCapture", "as_bgr", "open_device"]

log = logging.getLogger(__name__)

FRAME_SUFFIXES = (".png", ".jpg", ".jpeg")


def open_device(index: int) -> Any:
    """``cv2.VideoCapture(index)`` with OpenCV's own log at errors only while it opens: its backends warn on stderr
    as they probe for a device that is not there (``can't open camera by index``), before the camera says so in
    the artist's words."""
    level = cv2.utils.logging.getLogLevel()
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    try:
        return cv2.VideoCapture(index)
    finally:
        cv2.utils.logging.setLogLevel(level)


class FolderCapture:
    """A folder of frames with ``VideoCapture``'s methods: files in natural order (``f2`` before ``f10``)."""

    def __init__(self, folder: Path, fps: float):
        def key(p: Path) -> list:
            return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", p.name)]

        self.files = sorted((p for p in folder.iterdir() if p.suffix.lower() in FRAME_SUFFIXES), key=key)
        self.fps, self.pos = fps, 0

    def isOpened(self) -> bool:
        return bool(self.files)

    def read(self) -> tuple[bool, np.ndarray | None]:
        while self.pos < len(self.files):  # an unreadable file is skipped, as a dropped frame
            self.pos += 1
            image = cv2.imread(str(self.files[self.pos - 1]), cv2.IMREAD_COLOR)
            if image is not None:
                return True, image
            log.warning("skipping unreadable frame %s", self.files[self.pos - 1])
        return False, None

    def set(self, prop: int, value: float) -> bool:
        self.pos = int(value) if prop == cv2.CAP_PROP_POS_FRAMES else self.pos
        return prop == cv2.CAP_PROP_POS_FRAMES

    def get(self, prop: int) -> float:
        return self.fps if prop == cv2.CAP_PROP_FPS else 0.0

    def release(self) -> None:
        self.files = []


def as_bgr(image: Any) -> np.ndarray | None:
    """A source's picture as ``(H, W, 3)`` uint8 BGR (grey and BGRA converted), or None when it is no picture."""
    img = np.asarray(image) if image is not None else np.zeros((0, 0))
    channels = 1 if img.ndim == 2 else img.shape[-1]
    if img.dtype != np.uint8 or img.ndim not in (2, 3) or min(img.shape[:2]) < 1 or channels not in (1, 3, 4):
        return None
    return img if channels == 3 else cv2.cvtColor(img, cv2.COLOR_GRAY2BGR if channels == 1 else cv2.COLOR_BGRA2BGR)
