"""A camera read in its own thread: the latest frame, its capture time and a running index, always at hand.

``Camera(source)`` takes a device index (``0`` or ``"0"``), a video file or a folder of PNG/JPG frames (played as
a camera: at the file's own rate, optionally looping), or any object with OpenCV ``VideoCapture``'s methods
(``isOpened()``, ``read() -> (ok, image)``, ``release()``, optionally ``get(prop)``), such as
:class:`hardware.virtual_camera.VirtualCamera`. A reader thread keeps only the newest frame, so a slow consumer
never works on stale pictures::

    with Camera(0) as cam:
        frame = cam.latest()                               # Frame(image (H, W, 3) uint8 BGR, t, index)
        moved = time.monotonic()                            # ... the hand stopped moving here ...
        after = cam.wait_newer(moved, timeout_s=1.0)        # a frame captured strictly after that moment

``t`` is ``time.monotonic()`` when the frame arrived (a device may have exposed it a frame or two earlier: drivers
buffer). Errors (:mod:`hardware.errors`): :class:`CameraAbsent` (cannot open), :class:`CameraStalled` (no new frame
in time), :class:`CameraEnded` (a file played without looping is over). ``close()`` never raises, joins the thread.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from hardware.camera_sources import FolderCapture, as_bgr, open_device
from hardware.errors import CameraAbsent, CameraEnded, CameraError, CameraStalled
from studio.errors import ClosedError

__all__ = ["Camera", "Frame"]

log = logging.getLogger(__name__)

DEFAULT_FPS = 30.0  # the rate of a file whose own rate is unknown, and of a frame folder


@dataclass(frozen=True)
class Frame:
    """One picture from the camera."""

    image: np.ndarray  # (H, W, 3) uint8 BGR, read-only (shared by every caller that gets this frame)
    t: float  # time.monotonic() when it arrived from the source, s
    index: int  # running frame index since open(), from 0


class Camera:
    """The latest frame of ``source`` (module docstring). ``loop``: a file or folder starts again at its end (else
    it ends); ``fps``: a file's or folder's rate (default: the file's own, 30 for a folder); ``stall_s``: how long
    without a new frame counts as stalled (and how long ``latest`` waits for the first)."""

    JOIN_S = 1.0  # how long close() waits for the reader before releasing a source stuck in read()

    def __init__(self, source: Any, loop: bool = False, fps: float | None = None, stall_s: float = 2.0):
        if isinstance(source, str) and source.strip().isdigit():
            source = int(source.strip())
        self.source, self.loop, self.stall_s, self._fps_wanted = source, loop, float(stall_s), fps
        self.fps: float | None = None  # the rate a file or folder plays at; a device's or object's own, if known
        if isinstance(source, (str, Path)):
            self.name = f"{'frame folder' if Path(source).is_dir() else 'video file'} {source}"
        else:
            self.name = f"camera {source}" if isinstance(source, int) else f"camera source {type(source).__name__}"
        self._cap: Any = None
        self._paced = False  # a file or folder: frames published at its rate
        self._cond, self._stop = threading.Condition(), threading.Event()
        self._thread: threading.Thread | None = None
        self._frame: Frame | None = None
        self._arrived = 0.0  # monotonic time of the newest frame (or of open(), before the first)
        self.ended = False  # True once a file or folder played without looping is over
        self._error: BaseException | None = None
        self._released, self._closed = True, True  # not open (yet, or any more)

    # --- lifecycle -------------------------------------------------------------------------------------------
    def open(self) -> Camera:
        """Open the source (raising :class:`CameraAbsent` if it cannot be) and start the reader thread."""
        if self._thread is not None:
            return self
        self._cap = self._open_source()
        with self._cond:
            self._frame, self.ended, self._error, self._closed = None, False, None, False
            self._arrived, self._released = time.monotonic(), False
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"camera-reader ({self.name})", daemon=True)
        self._thread.start()
        log.info("%s open%s", self.name, f" at {self.fps:g} fps" if self.fps else "")
        return self

    def _open_source(self) -> Any:
        src = self.source
        if isinstance(src, int):
            cap = open_device(src)
            if not cap.isOpened():
                cap.release()
                raise CameraAbsent(f"no camera at index {src}: is it plugged in, free, and may this user open it?")
            self.fps = self._rate(cap, None)
            return cap
        if isinstance(src, (str, Path)):  # played as a camera
            path = Path(src)
            if path.is_dir():
                cap = FolderCapture(path, self._fps_wanted or DEFAULT_FPS)
                if not cap.isOpened():
                    raise CameraAbsent(f"no frames in frame folder {path} (PNG or JPG files)")
            elif not path.exists():
                raise CameraAbsent(f"video file not found: {path}")
            else:
                cap = cv2.VideoCapture(str(path))
                if not cap.isOpened():
                    cap.release()
                    raise CameraAbsent(f"cannot open video file {path}: OpenCV reads no video from it")
            self.fps, self._paced = self._rate(cap, self._fps_wanted) or DEFAULT_FPS, True
            return cap
        missing = [m for m in ("isOpened", "read", "release") if not callable(getattr(src, m, None))]
        if missing:
            raise CameraAbsent(f"not a camera source: {src!r} (needs isOpened, read and release; lacks {missing})")
        if not src.isOpened():
            raise CameraAbsent(f"{self.name} is not open")
        self.fps = self._rate(src, None)
        return src

    @staticmethod
    def _rate(cap: Any, wanted: float | None) -> float | None:
        try:
            fps = float(wanted or (cap.get(cv2.CAP_PROP_FPS) if callable(getattr(cap, "get", None)) else 0.0))
        except Exception:  # an object's get may not know the property
            fps = 0.0
        return fps if math.isfinite(fps) and 0 < fps <= 1000 else None

    def close(self) -> None:
        """Stop the reader and release the source; never raises, safe to call twice."""
        try:
            self._stop.set()
            thread, self._thread = self._thread, None
            for wait in (self.JOIN_S, self.JOIN_S / 2) if thread is not None else ():
                thread.join(timeout=wait)  # type: ignore[union-attr]
                self._release()  # a reader stuck inside the source's read() is unblocked by releasing it
            if thread is not None and thread.is_alive():
                log.warning("%s: the reader thread did not stop (its source's read() hangs)", self.name)
            self._release()
        except Exception:  # close must not raise: log and carry on
            log.exception("%s: error while closing", self.name)
        finally:
            with self._cond:
                self._closed = True
                self._cond.notify_all()

    def _release(self) -> None:
        with self._cond:
            if self._released or self._cap is None:
                return
            self._released = True
        try:
            self._cap.release()
        except Exception:
            log.exception("%s: release failed", self.name)

    def __enter__(self) -> Camera:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- the reader ------------------------------------------------------------------------------------------
    def _run(self) -> None:
        cap, period = self._cap, 1.0 / self.fps if self._paced and self.fps else 0.0
        index, due, since_rewind = 0, time.monotonic(), 0
        try:
            while not self._stop.is_set():
                ok, raw = cap.read()
                if self._stop.is_set():
                    break
                image = as_bgr(raw) if ok else None
                if image is None:
                    if ok:
                        raise CameraError(f"{self.name} gave a picture that is not an 8-bit image: {np.shape(raw)}")
                    if not self._paced:  # a device or object that missed a frame: try again (stalls are reported)
                        self._stop.wait(0.005)
                        continue
                    if self.loop and since_rewind > 0 and cap.set(cv2.CAP_PROP_POS_FRAMES, 0):
                        since_rewind = 0
                        continue
                    with self._cond:
                        self.ended = True
                        self._cond.notify_all()
                    log.info("%s ended after %d frames", self.name, index)
                    return
                if period:  # a file plays at its own rate, not as fast as it decodes
                    now = time.monotonic()
                    if due > now and self._stop.wait(due - now):
                        break
                    due = max(due + period, time.monotonic() - period)
                if image is raw and not self._paced:
                    image = image.copy()  # an object may reuse its buffer
                image.flags.writeable = False
                with self._cond:
                    self._arrived = time.monotonic()
                    self._frame = Frame(image, self._arrived, index)
                    self._cond.notify_all()
                index, since_rewind = index + 1, since_rewind + 1
        except BaseException as e:  # handed to the caller's thread
            log.debug("%s: reader failed: %r", self.name, e)
            with self._cond:
                self._error = e
                self._cond.notify_all()
        finally:
            self._release()

    # --- reading ---------------------------------------------------------------------------------------------
    def _check(self) -> None:
        """Raise what the reader met (called with the condition held)."""
        if self._closed:
            raise ClosedError(f"{self.name} is not open: call open() or use it in a with block")
        if (e := self._error) is not None:
            raise e if isinstance(e, CameraError) else CameraError(f"{self.name} failed: {e}")

    def latest(self) -> Frame:
        """The newest frame (waiting up to ``stall_s`` for the first). Raises :class:`CameraStalled` when no new
        frame has come for ``stall_s`` (a file that ended keeps its last frame), :class:`CameraEnded` when a file
        ended before giving any."""
        with self._cond:
            self._cond.wait_for(lambda: self._frame or self._error or self.ended or self._closed, self.stall_s)
            self._check()
            if self._frame is None:
                if self.ended:
                    raise CameraEnded(f"{self.name} has no readable frames")
                raise CameraStalled(f"{self.name} gave no frame within {self.stall_s:.1f} s of opening")
            age = time.monotonic() - self._arrived
            if not self.ended and age > self.stall_s:
                raise CameraStalled(f"{self.name} has given no new frame for {age:.1f} s (stalled)")
            return self._frame

    def wait_newer(self, after: int | float | Frame, timeout_s: float | None = None) -> Frame:
        """The first frame newer than ``after``: a frame index (int: index > after), a ``time.monotonic()`` moment
        (float: captured strictly after it) or a :class:`Frame`. Waits up to ``timeout_s`` (default ``stall_s``);
        raises :class:`CameraStalled` when none comes in time, :class:`CameraEnded` when a file is over."""
        after = after.index if isinstance(after, Frame) else after
        if isinstance(after, bool) or not isinstance(after, (int, float)):
            raise TypeError(f"wait_newer wants a frame index (int), a monotonic time (float) or a Frame: {after!r}")
        by_index = isinstance(after, int)
        timeout = self.stall_s if timeout_s is None else float(timeout_s)

        def newer() -> bool:
            return (f := self._frame) is not None and (f.index > after if by_index else f.t > after)

        with self._cond:
            self._cond.wait_for(lambda: newer() or self._error or self.ended or self._closed, timeout)
            self._check()
            if newer():
                return self._frame  # type: ignore[return-value]
            if self.ended:
                raise CameraEnded(f"{self.name} ended: no frame after {'index' if by_index else 't ='} {after}")
            what = f"frame {after}" if by_index else f"t = {after:.3f} s"
            raise CameraStalled(f"{self.name} gave no frame newer than {what} within {timeout:.1f} s (stalled)")
