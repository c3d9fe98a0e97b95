"""The virtual camera: the hand's true shadow, photographed, behind OpenCV ``VideoCapture``'s interface.

For tests, demos and benchmarks of the real rig's loop without a rig. Each ``read()`` takes the joint angles *at
that moment* from ``angles()`` (in practice :func:`emulator_angles`: the servo emulator's measured positions),
renders their shadow on the "true" rig (:class:`studio.sim.shadow.ShadowRenderer`, the mount roll included) at a
resolution finer than the photograph's pixels, and photographs the backdrop (:func:`studio.sim.photo.photograph`:
markers, perspective, light, blur, noise), paced to ``fps``. So ``Camera(VirtualCamera(...))`` reads it like a
device::

    with ServoEmulator() as emu, Camera(VirtualCamera(emulator_angles(emu, cal))) as cam:
        image = cam.latest().image   # (720, 960, 3) uint8 BGR
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import cv2
import numpy as np

from hardware.calibration import Calibration
from hardware.errors import ServoTimeout
from studio.sim.backdrop import BackdropLayout
from studio.sim.hand import Hand, load_hand
from studio.sim.photo import CameraModel, photograph
from studio.sim.shadow import Rig, ShadowRenderer

__all__ = ["VirtualCamera", "emulator_angles"]

log = logging.getLogger(__name__)


def emulator_angles(emulator: Any, calibration: Calibration) -> Callable[[], np.ndarray]:
    """A callable giving the hand's joint angles now, ``(J,)`` rad in the calibration's joint order (the hand's,
    as :func:`hardware.calibration.load_calibration` gives it), from ``emulator.positions()`` (``{id: servo
    units}``, :class:`hardware.emulator.ServoEmulator`) through :meth:`Calibration.to_rad`."""
    ids = calibration.ids

    def angles() -> np.ndarray:
        units = emulator.positions()
        missing = [i for i in ids if i not in units]
        if missing:
            raise ServoTimeout(missing[0], f"servo {missing[0]} is not on the emulated bus (IDs {sorted(units)})")
        return calibration.to_rad(np.array([units[i] for i in ids], dtype=float))

    return angles


class VirtualCamera:
    """A camera watching the backdrop of the true rig; ``VideoCapture``'s ``isOpened``, ``read``, ``release``,
    ``get``.

    ``angles``: called at every read, the joint angles ``(21,)`` rad now (clipped to the hand's limits: a servo may
    sit a hair past them). ``rig``: the true rig (light, backdrop, window, mount roll). ``camera``, ``layout``: the
    photograph's camera and the backdrop's markers. ``fps``: reads are paced to this rate (frames are captured at least
    ``1 / fps`` apart). ``render_resolution``: side of the rendered shadow window, pixels (default: about
    twice the photograph's pixels across the window, at least 512). The noise changes from frame to frame
    (``camera.seed`` + frame number).
    """

    def __init__(
        self,
        angles: Callable[[], np.ndarray],
        rig: Rig | None = None,
        camera: CameraModel | None = None,
        layout: BackdropLayout | None = None,
        fps: float = 30.0,
        render_resolution: int | None = None,
        hand: Hand | None = None,
    ):
        if not fps > 0:
            raise ValueError(f"fps must be positive, got {fps}")
        self.angles = angles
        self.rig = rig or Rig()
        self.camera = camera or CameraModel()
        self.layout = layout or BackdropLayout()
        self.fps = float(fps)
        self.hand = hand or load_hand()
        res = render_resolution or max(512, 2 * self._window_px())
        self.renderer = ShadowRenderer(self.hand, self.rig.with_resolution(int(res)))
        self.frames = 0  # frames read so far
        self._open = True
        self._due = time.monotonic()
        self._lock = threading.Lock()

    def _window_px(self) -> int:
        """About how many photograph pixels the window spans (from the camera's distance and field of view)."""
        dist = abs(self.camera.position_m[2] - self.rig.backdrop_z)
        px_m = 2 * dist * np.tan(np.radians(self.camera.fov_deg) / 2) / self.camera.width
        return int(np.ceil(self.rig.window / max(px_m, 1e-9)))

    def isOpened(self) -> bool:
        """True until ``release()``."""
        return self._open

    def read(self) -> tuple[bool, np.ndarray | None]:
        """``(True, image (H, W, 3) uint8 BGR)``: the backdrop now, paced to ``fps``; ``(False, None)`` once
        released."""
        with self._lock:
            if not self._open:
                return False, None
            now = time.monotonic()
            if self._due > now:
                time.sleep(self._due - now)
            self._due = time.monotonic() + 1.0 / self.fps  # frames captured at least 1 / fps apart
            theta = np.clip(np.asarray(self.angles(), dtype=np.float64), self.hand.lower, self.hand.upper)
            shadow = self.renderer.render_one(theta)
            cam = dataclasses.replace(self.camera, seed=self.camera.seed + self.frames)
            light_m = self.rig.light[2] - self.rig.backdrop_z
            image = photograph(shadow, self.rig.window, self.layout, cam, self.rig.backdrop_z, light_m)
            self.frames += 1
            return True, image

    def get(self, prop: int) -> float:
        """``cv2.CAP_PROP_FPS``, ``CAP_PROP_FRAME_WIDTH``, ``CAP_PROP_FRAME_HEIGHT``, ``CAP_PROP_FRAME_COUNT``
        (frames read so far); 0 for any other property, as OpenCV answers."""
        return {
            cv2.CAP_PROP_FPS: self.fps,
            cv2.CAP_PROP_FRAME_WIDTH: float(self.camera.width),
            cv2.CAP_PROP_FRAME_HEIGHT: float(self.camera.height),
            cv2.CAP_PROP_FRAME_COUNT: float(self.frames),
        }.get(prop, 0.0)

    def release(self) -> None:
        """Close it: later reads return ``(False, None)``."""
        self._open = False

    def __repr__(self) -> str:
        return (
            f"VirtualCamera({self.camera.width}×{self.camera.height} at {self.fps:g} fps, {self.rig.window} m window)"
        )
