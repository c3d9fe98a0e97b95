"""The show preview in the Review panel: a player over the show's time and the strip of every frame.

- :class:`ShowPlayer` (anywidget, ``show_player.js``): the preview's pre-rendered JPEG frames
  (:mod:`studio.project.preview`) played in the browser with ``requestAnimationFrame`` (play / pause, scrub, loop,
  speed 0.25×–2×) over the timeline image (:func:`studio.review.preview_strips.timeline_image`: keyframe ticks
  coloured by status, late transitions shaded) with a playhead; the kernel is free while it plays. The frame in view
  comes back as ``index``.
- :class:`FrameStrip` (anywidget, ``frame_strip.js``): every frame as ``target | shadow`` with its loss; a click
  sends its pixel, which :meth:`FrameStrip.click` turns into the frame it shows.
- :class:`ShowPreviewPanel`: both over a :class:`~widgets.state.StudioState`. A project change renders the preview
  again as a background job on the project's queue (progress and cancel here; a preview already rendered for the
  same content, :func:`~studio.project.preview.preview_key`, is reused). A click on the strip, or pausing or
  scrubbing the player, selects that frame in every tab; a selection made elsewhere moves the player there.
"""

from __future__ import annotations

import html
import logging
import threading
from collections import OrderedDict
from pathlib import Path
from typing import Any

import anywidget
import ipywidgets as w
import numpy as np
import traitlets as t

from hardware.player import PlayerConfig
from studio.project.preview import PreviewConfig, ShowPreview, frame_strip, preview_inputs, preview_job, preview_key
from studio.review.preview_strips import cell_at, timeline_image
from widgets.images import Messages, Throttle, png
from widgets.state import StudioState

log = logging.getLogger(__name__)

HERE = Path(__file__).parent
CACHED = 4  # previews kept per panel (by content hash), so undo / redo shows one again at once


class ShowPlayer(anywidget.AnyWidget):
    """Plays a :class:`~studio.project.preview.ShowPreview` in the browser (module doc)."""

    _esm = HERE / "show_player.js"
    frames = t.Bytes(b"").tag(sync=True)  # every frame's JPEG, one after another
    offsets = t.List(t.Int(), [0]).tag(sync=True)  # frame m is frames[offsets[m]:offsets[m + 1]]
    times = t.List(t.Float(), []).tag(sync=True)  # s, show time of each frame
    start = t.Float(0.0).tag(sync=True)  # s, the timeline's left end
    end = t.Float(1.0).tag(sync=True)  # s, the timeline's right end
    fps = t.Float(25.0).tag(sync=True)  # frames per second of show time at speed 1
    timeline = t.Bytes(b"").tag(sync=True)  # PNG of the timeline (ticks, late transitions)
    index = t.Int(0).tag(sync=True)  # the frame in view (set by the browser; set it here to seek)
    playing = t.Bool(False).tag(sync=True)  # playing now
    loop = t.Bool(True).tag(sync=True)  # start again at the end
    speed = t.Float(1.0).tag(sync=True)  # 0.25–2 × real time
    measured_fps = t.Float(0.0).tag(sync=True)  # frames a second the browser drew while playing (0: not played)

    def load(self, preview: ShowPreview, timeline_png: bytes) -> None:
        """Show ``preview`` (its frames and times) over the timeline image ``timeline_png``."""
        sizes = np.cumsum([0] + [len(f) for f in preview.frames]).tolist()
        clock = preview.clock
        with self.hold_sync():
            self.playing = False
            self.frames = b"".join(preview.frames)
            self.offsets = [int(x) for x in sizes]
            self.times = [float(x) for x in clock.times]
            self.start, self.end, self.fps = float(clock.start), float(clock.end), float(clock.fps)
            self.timeline = timeline_png
            self.index = min(self.index, max(0, len(preview.frames) - 1))

    @property
    def frame_count(self) -> int:
        return len(self.offsets) - 1

    def frame(self, m: int) -> bytes:
        """The JPEG of frame ``m``."""
        return self.frames[self.offsets[m] : self.offsets[m + 1]]


class FrameStrip(anywidget.AnyWidget):
    """Every frame as ``target | shadow`` (module doc); ``on_pick(frame)`` is called for a click on a cell."""

    _esm = HERE / "frame_strip.js"
    image = t.Bytes(b"").tag(sync=True)  # PNG of the strip
    boxes = t.List(t.List(t.Int()), []).tag(sync=True)  # (x, y, w, h) px of each frame's cell in the image
    selected = t.Int(0).tag(sync=True)  # the frame framed in the strip
    height = t.Int(220).tag(sync=True)  # px of the strip's scrolled box

    def __init__(self, on_pick=None, **kwargs: Any):
        super().__init__(**kwargs)
        self.on_pick = on_pick
        self.on_msg(self._message)

    def _message(self, _widget: Any, content: dict, _buffers: Any) -> None:
        if isinstance(content, dict) and content.get("type") == "click":
            self.click(float(content.get("x", -1)), float(content.get("y", -1)))

    def click(self, x: float, y: float) -> int | None:
        """A click at pixel ``(x, y)`` of the image (what the browser sends): its frame is picked (None: a gap)."""
        frame = cell_at(self.boxes, x, y)
        if frame is not None and self.on_pick is not None:
            self.on_pick(frame)
        return frame


class ShowPreviewPanel:
    """The player and the strip over ``state`` (module doc); ``.widget`` goes in the Review panel."""

    def __init__(self, state: StudioState, cfg: PreviewConfig | None = None, strip_tile: int = 64,
                 strip_columns: int = 8, timeline_px: int = 640):  # fmt: skip
        self.state = state
        self.cfg = cfg or PreviewConfig(home=PlayerConfig().ramp_speed_rad_s)  # a still: the move from home, as played
        self.strip_tile, self.strip_columns, self.timeline_px = strip_tile, strip_columns, timeline_px
        self.messages = Messages()
        self.player = ShowPlayer()
        self.strip = FrameStrip(on_pick=lambda f: self.state.select(frame=f))
        self.note = w.HTML("")
        self.progress = w.FloatProgress(value=0, min=0, max=1, description="preview", layout={"width": "320px"})
        self.cancel_button = w.Button(description="Cancel", icon="stop", disabled=True)
        self.cancel_button.on_click(lambda _: self.cancel())
        self.preview: ShowPreview | None = None  # the preview in the player
        self.job = None  # the preview job rendering now
        self.key: str | None = None  # the content hash of the preview the project needs now
        self._cache: OrderedDict[str, ShowPreview] = OrderedDict()
        self._lock = threading.RLock()
        self.player.observe(self._player_moved, names=["index", "playing"])
        self.widget = w.VBox([
            w.HTML("<b>show preview</b> (source | target | shadow)"), self.player, self.note,
            w.HBox([self.progress, self.cancel_button]), w.HTML("<b>frames</b> (click one to select it)"),
            self.strip, self.messages.widget,
        ])  # fmt: skip
        self.refresher = Throttle(lambda: self.refresh(), hz=4.0)  # refresh() in the panel's thread after an edit
        self._stops = [state.on_change(self._changed), state.queue.subscribe(self._job_event)]
        self.refresher()

    # ---------------------------------------------------------------- rendering
    def refresh(self) -> None:
        """Bring the strip and the preview up to date with the project (a render job when the content changed); the
        panel asks :attr:`refresher` to, so that the strip (every frame drawn: 0.4 s at 240 frames) and the preview's
        content hash are worked out in its own thread, never an edit's."""
        self.messages.run(self._draw_strip)
        self.messages.run(self._want_preview, clear=False)

    def _draw_strip(self) -> None:
        img, boxes = frame_strip(self.state.project, self.strip_tile, self.strip_columns)
        with self.strip.hold_sync():
            self.strip.image, self.strip.boxes = png(img), [list(b) for b in boxes]
            self.strip.selected = self.state.selection.frame

    def _want_preview(self) -> None:
        inp = preview_inputs(self.state.project)
        key = preview_key(inp, self.cfg)
        with self._lock:
            self.key = key
            if self.preview is not None and self.preview.key == key:
                return
            if key in self._cache:
                self._show(self._cache[key])
                return
            if self.job is not None and self.job.meta.get("key") == key and not self.job.finished:
                return
            self.cancel()
            self.job = self.state.queue.submit(preview_job(self.state.project, self.cfg, apply=self._rendered))
            self.progress.value, self.cancel_button.disabled = 0.0, False
            self.note.value = "rendering the preview …"

    def _rendered(self, preview: ShowPreview | None) -> None:
        """The job's result (on the queue's thread): cached, and shown when it is what the project needs now."""
        if preview is None:
            return
        with self._lock:
            self._cache[preview.key] = preview
            while len(self._cache) > CACHED:
                self._cache.popitem(last=False)
            if preview.key == self.key:
                self._show(preview)

    def _show(self, preview: ShowPreview) -> None:
        self.preview = preview
        timeline = png(timeline_image(preview.clock, self.timeline_px))
        self.player.load(preview, timeline)
        self.cancel_button.disabled = True
        self.progress.value = 1.0
        c = preview.clock
        self.note.value = html.escape(
            f"{c.note} · {len(preview.frames)} frames at {c.fps:g} fps, {preview.nbytes / 1e6:.2f} MB, "
            f"rendered in {preview.seconds:.1f} s"
        )
        self._follow_selection()

    def cancel(self) -> None:
        """Cancel the preview job rendering now (nothing changes in the player)."""
        job, self.job = self.job, None
        if job is not None and not job.finished:
            job.cancel()
            self.note.value = "preview cancelled"
        self.cancel_button.disabled = True

    def _job_event(self, event: Any) -> None:
        job = self.job
        if job is None or event.job_id != job.id:
            return
        state = getattr(event.state, "value", str(event.state))
        if event.total > 0 and event.stage == "preview":
            self.progress.value = event.step / event.total
        if state == "failed":
            self.messages.say(f"the preview could not be rendered: {event.error}", error=True)
            self.note.value, self.cancel_button.disabled = "no preview (see below)", True

    # ---------------------------------------------------------------- the selection
    def frame_shown(self) -> int | None:
        """The project frame in the player's view (None: no preview yet)."""
        p = self.preview
        if p is None or not len(p.clock.frame):
            return None
        return int(p.clock.frame[max(0, min(self.player.index, len(p.clock.frame) - 1))])

    def _player_moved(self, _change: dict) -> None:
        frame = self.frame_shown()
        if frame is None or self.player.playing or frame == self.state.selection.frame:
            return
        self.state.select(frame=frame)

    def _follow_selection(self) -> None:
        """Frame the selected frame in the strip and move the player to where it first plays (unless it is there)."""
        f = self.state.selection.frame
        self.strip.selected = f
        p = self.preview
        if p is None or self.player.playing or self.frame_shown() == f:
            return
        at = np.flatnonzero(p.clock.frame == f)
        if len(at):
            self.player.index = int(at[0])

    def _changed(self, what: str) -> None:
        if what == "project":
            self.refresher()
        elif what == "selection":
            self._follow_selection()

    def close(self) -> None:
        """Stop following the state and cancel a preview being rendered."""
        for stop in self._stops:
            stop()
        self.refresher.close(wait_s=5.0)
        self.cancel()
