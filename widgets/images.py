"""Small helpers the panels share: masks and frames → PNG bytes for ``ipywidgets.Image``, overlays, a throttle, and
an error line instead of a traceback (DESIGN §5.7, §6 "ipywidgets from a thread")."""

from __future__ import annotations

import atexit
import html
import logging
import threading
import time
import weakref
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import ipywidgets as w
import numpy as np

from studio.errors import StudioError

log = logging.getLogger(__name__)

ADD_RGB = (60, 200, 90)  # painted additions
ERASE_RGB = (230, 60, 60)  # painted erasures
MASK_RGB = (255, 170, 0)  # an automatic / binary mask over a frame
FRAME_EDGE = "1px solid #bbb"  # the CSS border of a frame's picture (its white backdrop meets the white page)
EXIT_WAIT_S = 10.0  # s the interpreter waits at exit for the panels' background work (below) to end


def frame_in_view(state: Any) -> int:
    """``state.selection.frame`` clamped to the project's frames (an undo may have removed the one in view)."""
    n = len(state.project.frames)
    return max(0, min(state.selection.frame, n - 1))


def title(text: str) -> w.HTML:
    """The panel's visible title label (the browser test looks for it)."""
    return w.HTML(f"<b style='font-size:1.2em'>{text}</b>")


def legend(entries: Sequence[tuple[tuple[int, int, int], str]], then: str = "") -> w.HTML:
    """A line naming what each colour of a picture means: a square of each ``(rgb, words)``, then ``then``."""
    keys = "&ensp;".join(
        f'<span style="display:inline-block;width:0.9em;height:0.9em;margin-right:0.3em;vertical-align:-0.1em;'
        f'background:rgb{tuple(rgb)}"></span>{html.escape(words)}'
        for rgb, words in entries
    )
    return w.HTML(keys + (f"&ensp;·&ensp;{html.escape(then)}" if then else ""))


def grey_rgb(image: np.ndarray) -> np.ndarray:
    """``(H, W)`` grey or ``{0, 1}`` mask, or ``(H, W, 3)`` → ``(H, W, 3)`` uint8 RGB (a {0, 1} mask: black shape
    on white)."""
    a = np.asarray(image)
    if a.ndim == 3:
        return a.astype(np.uint8)
    if a.max(initial=0) <= 1:
        a = (1 - a.astype(np.uint8)) * 255
    return np.repeat(a.astype(np.uint8)[..., None], 3, axis=2)


def tint(rgb: np.ndarray, mask: np.ndarray, colour: tuple[int, int, int], alpha: float = 0.5) -> np.ndarray:
    """``rgb (H, W, 3)`` with ``mask (H, W)`` (nonzero) blended towards ``colour``; a new array."""
    out = rgb.astype(np.float32)
    m = np.asarray(mask) != 0
    out[m] = (1 - alpha) * out[m] + alpha * np.asarray(colour, np.float32)
    return out.astype(np.uint8)


def stroke_mask(
    points: Sequence[tuple[float, float]], radius: float, scale: float, shape: tuple[int, int]
) -> np.ndarray:
    """A brush stroke through ``points`` ``[(x, y), ...]`` (canvas px) with a round brush of ``radius`` canvas px, as
    ``shape`` ``(H, W)`` uint8 {0, 1} in pixels of ``scale`` × a canvas pixel's size."""
    out = np.zeros(shape, np.uint8)
    pts = [(int(round(x * scale - 0.5)), int(round(y * scale - 0.5))) for x, y in points]
    r = max(0, int(round(radius * scale)))
    for a, b in zip(pts, pts[1:], strict=False):
        cv2.line(out, a, b, 1, thickness=max(1, 2 * r + 1))
    for p in pts:
        cv2.circle(out, p, r, 1, thickness=-1)
    return out


def upscale(image: np.ndarray, side: int) -> np.ndarray:
    """``image (H, W[, 3])`` resized to ``(side, side[, 3])``, nearest pixel (masks stay crisp)."""
    return cv2.resize(np.ascontiguousarray(image), (side, side), interpolation=cv2.INTER_NEAREST)


def png(image: np.ndarray) -> bytes:
    """``(H, W)`` grey or ``(H, W, 3)`` RGB uint8 → PNG bytes for ``ipywidgets.Image``."""
    a = np.ascontiguousarray(image, np.uint8)
    if a.ndim == 3:
        a = cv2.cvtColor(a, cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", a)
    if not ok:
        raise ValueError(f"could not encode an image of shape {a.shape} as PNG")
    return buf.tobytes()


def shown_when_drawn(image: w.Image) -> w.Image:
    """``image``, laid out only while it holds a picture: an empty ``ipywidgets.Image`` is drawn as the browser's
    broken-picture icon, so a picture not made yet (a camera frame, a comparison) takes no room instead."""

    def fit(_change: object = None) -> None:
        image.layout.display = None if image.value else "none"

    image.observe(fit, names="value")
    fit()
    return image


def frame_picture(side: int, value: bytes = b"") -> w.Image:
    """A square PNG image widget ``side`` px wide for a frame (a mask, a shadow: white backdrop), drawn with the
    frame's edge (:data:`FRAME_EDGE`): where a shape sits in its frame matters (the hand can change a shadow's shape,
    never move it), and a white backdrop on the white page shows no edge."""
    return w.Image(value=value, format="png", width=side, height=side, layout={"border": FRAME_EDGE})


class Messages:
    """One line in a panel saying what went wrong (never a traceback in the output area)."""

    def __init__(self) -> None:
        self.widget = w.HTML("")

    @property
    def text(self) -> str:
        return self.widget.value

    def say(self, text: str, error: bool = False) -> None:
        colour = "#b00" if error else "#555"
        shown = html.escape(text, quote=False)  # a message may quote a shared project's names: never markup
        self.widget.value = f"<span style='color:{colour}'>{shown}</span>" if text else ""

    def run(self, fn: Callable[..., Any], *args: Any, clear: bool = True, **kwargs: Any) -> Any:
        """``fn(*args, **kwargs)``; an error is shown here (and logged), never raised; returns fn's result or None.
        ``clear``: the previous message goes first (a redraw keeps it)."""
        if clear:
            self.say("")
        try:
            return fn(*args, **kwargs)
        except (StudioError, ValueError, KeyError, OSError) as e:
            self.say(str(e).strip("'\""), error=True)
            log.info("panel action failed: %s", e)
            return None
        except Exception as e:  # a panel must never leave a traceback in the notebook
            self.say(f"unexpected error ({type(e).__name__}): {e}", error=True)
            log.debug("panel action failed", exc_info=True)
            return None


_background: list[threading.Thread] = []  # the panels' background threads, waited for at exit
_throttles: weakref.WeakSet = weakref.WeakSet()  # every Throttle, closed at exit


def background(target: Callable[[], None], name: str) -> threading.Thread:
    """Run ``target()`` in a daemon thread that the interpreter waits for (up to :data:`EXIT_WAIT_S`) when it exits:
    a daemon thread stopped at exit while inside OpenCV's or torch's C++ code aborts the whole process."""
    thread = threading.Thread(target=target, name=name, daemon=True)
    _background[:] = [t for t in _background if t.is_alive()] + [thread]
    thread.start()
    return thread


@atexit.register
def _wait_for_background() -> None:
    for throttle in list(_throttles):
        throttle.close()
    deadline = time.monotonic() + EXIT_WAIT_S
    for thread in list(_background):
        thread.join(max(0.0, deadline - time.monotonic()))


class Throttle:
    """Call a function in a thread of its own, never the caller's (a draw that takes seconds, a large photo's, must not
    hold the notebook), at most ``hz`` times a second, the latest request last: requests made while it runs are
    served by one more call when it ends, never a backlog (DESIGN §6: one writer thread per widget, 10–30 Hz)."""

    def __init__(self, fn: Callable[[], None], hz: float = 15.0):
        self.fn = fn  # what to call (no arguments)
        self.interval = 1.0 / hz  # s between calls
        self._wanted = threading.Event()
        self._idle = threading.Event()  # set while nothing is asked for nor being drawn
        self._idle.set()
        self._closed = False
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        _throttles.add(self)

    def __call__(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._idle.clear()
            self._wanted.set()
            if self._thread is None:
                self._thread = background(self._serve, "throttled-draw")

    def settle(self, timeout: float = 10.0) -> bool:
        """Wait until every request so far has been served (True), or ``timeout`` s (False)."""
        return self._idle.wait(timeout)

    def close(self, wait_s: float = 0.0) -> None:
        """Serve no more requests: the thread ends after a call in progress, waited for up to ``wait_s`` s (for a
        caller about to release what the calls use)."""
        with self._lock:
            self._closed = True
            self._wanted.set()
            thread = self._thread
        if wait_s > 0 and thread is not None and thread is not threading.current_thread():
            thread.join(wait_s)

    def _serve(self) -> None:
        last = -1e9
        while True:
            self._wanted.wait()
            time.sleep(max(0.0, last + self.interval - time.monotonic()))
            with self._lock:
                if self._closed:
                    return
                self._wanted.clear()
            last = time.monotonic()
            try:
                self.fn()
            except Exception:
                log.debug("throttled redraw failed", exc_info=True)
            with self._lock:
                if not self._wanted.is_set():
                    self._idle.set()


def mask_picture(mask: np.ndarray | None, side: int) -> bytes:
    """PNG of a ``(H, W)`` {0, 1} mask as a black shape on white, ``side`` px (an empty white square for None)."""
    if mask is None:
        return png(np.full((side, side, 3), 255, np.uint8))
    return png(upscale(grey_rgb(np.asarray(mask, np.uint8)), side))
