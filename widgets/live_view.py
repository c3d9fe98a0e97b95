"""What the Live panel shows while a session runs: the camera's frame | the target the hand follows | the shadow of
the pose it is commanded to, side by side, and a status line (updates a second, latency, loss, why the hand holds).

The engine's updates (:class:`~studio.project.live.LiveUpdate`) come from its planner thread: :meth:`LiveView.offer`
only keeps the newest and counts it, so the planner never waits on a picture. A drawer thread of the view's own
encodes and sets the pictures at most ``redraw_hz`` a second (DESIGN §6: one writer thread per widget, throttled);
:meth:`LiveView.end` joins it and draws the last update. While the hand holds the pictures stay as they were: a
stalled camera keeps its last frame, the commanded shadow stays the last commanded one; a frame without a silhouette
shows an empty (white) target. Shadows are drawn as :func:`widgets.images.mask_picture` draws masks: black on white.
:func:`ended_line` says how a session ended; :func:`check_roll` refuses a roll the calibration does not record.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import ipywidgets as w
import numpy as np

from hardware.calibration import Calibration
from hardware.show_checks import calibrated_roll_conflict
from widgets.images import FRAME_EDGE, mask_picture, png

if TYPE_CHECKING:
    from studio.project.live import LiveResult
    from studio.project.live_config import LiveConfig

log = logging.getLogger(__name__)

RATE_WINDOW_S = 2.0  # updates a second are counted over this much of the recent past, s
PICTURES = ("camera", "target", "shadow")  # the three pictures, left to right


def camera_picture(image_bgr: np.ndarray, width: int) -> np.ndarray:
    """A camera frame ``(H, W, 3)`` uint8 BGR → RGB ``(h, width, 3)`` uint8, its aspect kept."""
    h, wd = image_bgr.shape[:2]
    size = (width, max(1, round(h * width / wd)))
    how = cv2.INTER_AREA if wd > width else cv2.INTER_LINEAR
    return cv2.cvtColor(cv2.resize(np.ascontiguousarray(image_bgr), size, interpolation=how), cv2.COLOR_BGR2RGB)


def shadow_picture(mask: np.ndarray | None, side: int) -> bytes:
    """PNG of a target or shadow ``(R, R)`` (nonzero = shadow) as black on white, ``side`` px (None: white)."""
    return mask_picture(None if mask is None else (np.asarray(mask) > 0).astype(np.uint8), side)


def status_line(u: Any, per_s: float) -> str:
    """One update in words: updates a second, the median latency so far, the commanded pose's loss, what it does."""
    lat = "–" if not math.isfinite(u.latency_s) else f"{u.latency_s * 1000:.0f} ms"
    loss = "–" if not math.isfinite(u.loss) else f"{u.loss:.3f}"
    return f"{per_s:.1f} updates/s · latency {lat} · loss {loss} · {u.status or 'following the camera'}"


class UpdateRate:
    """Targets handed to the motion a second, over the last :data:`RATE_WINDOW_S` (one writer thread)."""

    def __init__(self) -> None:
        self.times: deque[float] = deque()  # monotonic times of the recent updates that carried a target

    def add(self, now: float, sent: bool) -> float:
        """Count an update (``sent``: it carried a target) at ``now``; the rate at ``now`` (0 while it holds)."""
        if sent:
            self.times.append(now)
        while self.times and self.times[0] < now - RATE_WINDOW_S:
            self.times.popleft()
        return (len(self.times) - 1) / max(now - self.times[0], 1e-3) if len(self.times) > 1 else 0.0


class LiveView:
    """The three pictures and the status line (``widget``); ``drawn[name]`` is the update a picture shows now."""

    def __init__(self, tile: int = 240, redraw_hz: float = 10.0):
        self.tile = tile  # side of the target and shadow pictures, and the camera picture's width, px
        self.interval = 1.0 / min(max(redraw_hz, 0.1), 10.0)  # s between redraws, at least 0.1
        edge = {"camera": None, "target": FRAME_EDGE, "shadow": FRAME_EDGE}  # the frames' edges (not the camera's)
        self.pictures = {n: w.Image(format="png", layout=w.Layout(width=f"{tile}px", border=edge[n])) for n in PICTURES}
        self.status = w.Label("")
        captions = ("camera", "target (what the hand follows)", "shadow of the commanded pose")
        columns = [w.VBox([w.HTML(f"<i>{c}</i>"), self.pictures[n]]) for c, n in zip(captions, PICTURES, strict=True)]
        self.widget = w.VBox([w.HBox(columns), self.status])
        self.drawn: dict[str, Any] = {}  # picture name → the LiveUpdate it shows
        self.offered = 0  # updates offered since begin()
        self.draws = 0  # redraws since begin()
        self._latest: tuple[Any, float] | None = None  # (update, rate) not drawn yet
        self._rate = UpdateRate()
        self._wake, self._done = threading.Event(), threading.Event()
        self._thread: threading.Thread | None = None
        self.clear()

    def clear(self) -> None:
        """White pictures, no status (before any session)."""
        for name in PICTURES:
            self.pictures[name].value = shadow_picture(None, self.tile)
        self.drawn, self.status.value = {}, ""

    def show_frame(self, image_bgr: np.ndarray) -> None:
        """Show a camera frame now (the camera's first picture, before a session runs; not while drawing)."""
        self.pictures["camera"].value = png(camera_picture(image_bgr, self.tile))

    def begin(self) -> None:
        """Start the drawer for a new session."""
        self.end()
        self._rate, self._latest, self.offered, self.draws = UpdateRate(), None, 0, 0
        self._wake.clear()
        self._done.clear()
        self._thread = threading.Thread(target=self._run, name="live-view", daemon=True)
        self._thread.start()

    def offer(self, u: Any) -> None:
        """A :class:`~studio.project.live.LiveUpdate` from the planner's thread: kept, counted, drawn later."""
        now = time.monotonic()
        self._latest = (u, self._rate.add(now, u.theta is not None))
        self.offered += 1
        self._wake.set()

    def end(self) -> None:
        """Stop the drawer, join it, then draw the newest update it had not drawn yet."""
        thread, self._thread = self._thread, None
        if thread is None:
            return
        self._done.set()
        self._wake.set()
        thread.join(5.0)
        self._draw_latest()

    def _run(self) -> None:
        while not self._done.is_set():
            self._wake.wait(0.5)
            if self._done.is_set():
                return
            self._wake.clear()
            t0 = time.monotonic()
            self._draw_latest()
            self._done.wait(max(0.0, self.interval - (time.monotonic() - t0)))

    def _draw_latest(self) -> None:
        got, self._latest = self._latest, None
        if got is None:
            return
        try:
            self.draw(*got)
        except Exception:  # a picture must never stop the session, nor leave a traceback
            log.debug("the live view failed to draw an update", exc_info=True)

    def draw(self, u: Any, per_s: float) -> None:
        """Draw one update (the drawer's thread): the pictures it carries, and the status line."""
        if u.image.ndim == 3 and u.image.shape[0] > 1:  # a stalled camera's update carries no frame
            self.pictures["camera"].value = png(camera_picture(u.image, self.tile))
            self.drawn["camera"] = u
        if u.target is not None or u.frame_index >= 0:  # a frame without a silhouette: an empty target
            self.pictures["target"].value = shadow_picture(u.target, self.tile)
            self.drawn["target"] = u
        if u.shadow is not None:  # holding: the commanded shadow stays
            self.pictures["shadow"].value = shadow_picture(u.shadow, self.tile)
            self.drawn["shadow"] = u
        self.status.value = status_line(u, per_s)
        self.draws += 1


def check_roll(roll_deg: float, cal: Calibration) -> None:
    """A ValueError in the panel's words when the calibration records another mount roll than ``roll_deg``."""
    have = calibrated_roll_conflict(math.radians(roll_deg), cal)  # the rule check_mount asks, in the panel's words
    if have is not None:
        raise ValueError(f"the calibration records the hand mounted at roll {have:+.1f}°, not {roll_deg:+.1f}°: "
                         f"set the roll to {have:.1f}°, or measure the rig again in the Rig panel")  # fmt: skip


def ended_line(result: LiveResult, cfg: LiveConfig, stopped: bool, left: str, folder: Path, files: list[Path]) -> str:
    """How a session ended, in one line: why, how it went, how the servos are left, where its files are."""
    s = result.summary()
    reason = result.playback.reason.value
    if reason == "e-stop":
        why = "E-STOP: the hand stopped at once and the e-stop is latched (press reset e-stop to move again)"
    elif result.error:
        why = f"ended early: {result.error}"
    elif stopped:
        why = "stopped: you pressed Stop"
    elif reason == "completed" and cfg.max_seconds and result.seconds >= cfg.max_seconds - 0.5:
        why = f"ended after its {cfg.max_seconds:g} s"
    elif reason == "completed":
        why = "ended: the video is over and the hand rests on its last pose"
    else:
        why = f"stopped ({reason}): {result.playback.message}"
    figures = f"{s['updates']} updates in {s['seconds']:.1f} s ({s['updates_per_s']:.1f}/s)"
    if s["latency_p50_ms"] is not None:
        figures += f", latency {s['latency_p50_ms']:.0f} ms (p99 {s['latency_p99_ms']:.0f} ms)"
    if s["mean_loss"] is not None:
        figures += f", mean loss {s['mean_loss']:.3f}"
    if s["holds"]:
        held, n = max(s["holds"].items(), key=lambda kv: kv[1])
        figures += f", held {n}× ({held.removeprefix('holding: ')})"
    what = "log and recording" if len(files) > 1 else "log"
    return f"{why}; {figures}; {left}; {what} in {folder}"
