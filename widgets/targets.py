"""The Targets panel: sources (a bundled sample, a file path or an upload), a frame scrubber, the sampling rate, the
threshold (or Otsu) with a live preview of the binary mask over the frame beside the mask the project would store
after its cleanup, and segmentation of raw colour footage from a first-frame box or a mask painted on the first frame
(:mod:`widgets.first_frame`). What the buttons do (:mod:`widgets.targets_actions`) reads the sources again, so it
runs as a job on the project's queue, followed in the panel's job line, with Cancel.

    panel = TargetsPanel(state)      # panel.widget goes in the notebook; tests set values and .click() buttons

The left picture is the threshold alone on the frame's shadowness, the right one what the project stores at that
threshold after its cleanup (ruled lines, specks, pieces, holes; a still's crease pockets as the checkbox says), both
in the project's square frame, decided in source pixels with the source's polarity as the project finds it
(:mod:`widgets.target_preview`), drawn in the panel's own thread (``drawer``); the project changes when applied.
"""

from __future__ import annotations

import html
import threading
from dataclasses import replace
from pathlib import Path

import cv2
import ipywidgets as w
import numpy as np
from studio.assets import shipped_samples

from studio.errors import count
from studio.jobs import Job
from studio.project.sources import locate
from studio.project.state import ProjectError
from studio.targets.pockets import POCKET_REACH
from studio.targets.source import raw_frames
from widgets.first_frame import FirstFrame
from widgets.images import MASK_RGB, Messages, Throttle, frame_in_view, grey_rgb, mask_picture, png, tint, title
from widgets.relink import RelinkControl
from widgets.state import StudioState
from widgets.target_preview import frame_preview, source_polarity
from widgets.targets_actions import TargetsActions
from widgets.words import seconds

PREVIEW_PX = 256  # side of the preview image, px
POLARITY_WORDS = {"dark": "a dark shape on a light ground", "bright": "a bright shape on a dark ground"}


class TargetsPanel(TargetsActions):
    """The Targets panel (module doc) over ``state``; ``.widget`` is what the notebook shows."""

    def __init__(self, state: StudioState):
        self.state = state
        self.messages = Messages()
        self._raw: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # source → (grey frames (N, H, W), source indices)
        self._raw_key: object = None
        self.pending: Path | None = None  # raw colour footage waiting for its object in the first frame
        self.preview_level = float("nan")  # the threshold the preview used (Otsu's when Otsu is on)
        self.preview_mask: np.ndarray | None = None  # (PREVIEW_PX, PREVIEW_PX) uint8 {0, 1}: the previewed mask
        self.stored_mask: np.ndarray | None = None  # (PREVIEW_PX, PREVIEW_PX) uint8 {0, 1}: … after the cleanup
        self.stored_rgb: np.ndarray | None = None  # (PREVIEW_PX, PREVIEW_PX, 3) uint8: what the stored picture shows
        self._polarity: dict[int, str] = {}  # source → its polarity, as the project finds it (module doc)
        self.job: Job | None = None  # the panel's last job (an edit that reads the sources: module doc of the actions)
        self.preview_rgb: np.ndarray | None = None  # (PREVIEW_PX, PREVIEW_PX, 3) uint8: what the preview shows
        self._first_source: tuple | None = None  # (source, path, box) whose first frame the first-frame picture has
        self._drawing = threading.RLock()  # one preview drawn at a time: a late throttled draw never lands last stale

        samples = shipped_samples()
        self.sample = w.Dropdown(options=list(samples), description="sample")
        self._samples = samples
        self.add_sample = w.Button(description="Add sample", icon="plus")
        self.path = w.Text(placeholder="a still, a video or a folder of frames", description="file")
        self.add_path = w.Button(description="Add file", icon="plus")
        self.upload = w.FileUpload(accept="image/*,video/*,.gif", multiple=False, description="Upload")
        self.sources = w.HTML()
        self.scrubber = w.IntSlider(min=0, max=0, description="frame", continuous_update=True)
        self.frame_info = w.Label()
        blank = mask_picture(None, PREVIEW_PX)  # until the first draw lands (an empty image: a broken-picture icon)
        self.preview = w.Image(value=blank, format="png", width=PREVIEW_PX, height=PREVIEW_PX)
        self.stored = w.Image(value=blank, format="png", width=PREVIEW_PX, height=PREVIEW_PX)  # after the cleanup
        self.stored_info = w.HTML()
        self.hz = w.BoundedFloatText(min=0.1, max=60.0, step=0.5, description="sampling Hz")
        self.apply_hz = w.Button(description="Apply sampling")
        self.threshold = w.FloatSlider(min=0.0, max=254.0, step=1.0, description="threshold", continuous_update=True)
        self.otsu = w.Checkbox(description="Otsu")
        self.pockets = w.Checkbox(description="fill crease pockets")  # a still's: its shade cut in as a notch is skin
        self.apply_threshold = w.Button(description="Apply")
        self.first = FirstFrame(PREVIEW_PX, on_change=self._first_changed)  # the object: a box or a painted mask
        self.box = self.first.box  # x, y, w, h (source pixels)
        self.segment = w.Button(description="Segment", icon="scissors")
        self.cancel_job = w.Button(description="Cancel", icon="stop", disabled=True)  # stops the panel's job
        self.job_info = w.Label()  # what the panel's job is doing
        self.relink = RelinkControl(state, self.messages, self._relink)  # shown while a source is missing

        self.add_sample.on_click(lambda _: self.messages.run(self._add, self._samples[self.sample.value]))
        self.add_path.on_click(lambda _: self.messages.run(self._add, Path(self.path.value.strip()).expanduser()))
        self.upload.observe(lambda ch: self.messages.run(self._uploaded, ch["new"]), names="value")
        self.scrubber.observe(self._scrubbed, names="value")
        self.apply_hz.on_click(lambda _: self.messages.run(self._apply_sampling))
        self.drawer = Throttle(lambda: self.messages.run(self.refresh_preview, clear=False), hz=15.0)
        self._throttled = self.drawer  # asks for a preview (drawn in the drawer's thread, the latest state last)
        self.threshold.observe(lambda _: self._throttled(), names="value")
        self.otsu.observe(lambda _: self._throttled(), names="value")
        self.pockets.observe(lambda _: self._throttled(), names="value")
        self.apply_threshold.on_click(lambda _: self.messages.run(self._apply_threshold))
        self.segment.on_click(lambda _: self.messages.run(self._segment))
        self.cancel_job.on_click(lambda _: self.job is not None and self.job.cancel())

        self.pictures = w.HBox([
            w.VBox([w.HTML("threshold alone"), self.preview]),
            w.VBox([w.HTML("stored (after cleanup)"), self.stored, self.stored_info],
                   layout=w.Layout(width=f"{PREVIEW_PX + 20}px")),
        ])  # fmt: skip
        self.widget = w.VBox([
            title("Targets"),
            self.sources,
            self.relink.widget,
            w.HBox([self.sample, self.add_sample]),
            w.HBox([self.path, self.add_path, self.upload]),
            w.HBox([self.scrubber, self.frame_info]),
            self.pictures,
            w.HBox([self.threshold, self.otsu, self.pockets, self.apply_threshold]),
            w.HBox([self.hz, self.apply_hz]),
            self.first.widget,
            w.HBox([self.segment, self.cancel_job]),
            self.job_info,
            self.messages.widget,
        ])  # fmt: skip
        self._stops = [
            state.on_change(self._changed),
            state.queue.subscribe(self._job_event),  # the queue's thread: the job line, the buttons, messages
        ]
        self.first.widget.layout.display = "none"
        self.redraw()

    def close(self) -> None:
        """Stop following the state (the widget stays as it is)."""
        for stop in self._stops:
            stop()
        self.drawer.close()

    # ---------------------------------------------------------------- reading the project
    def _source_index(self) -> int:
        frames = self.state.project.frames
        return frames[frame_in_view(self.state)].source if frames else 0

    def _is_still(self, source: int) -> bool:
        return self.state.project.sources[source].kind == "still"

    def _raw_grey(self, frame: int) -> np.ndarray:
        """The selected frame as grey levels ``(H, W)`` in source pixels (read once per source and settings)."""
        s = self.state.project.state
        key = (s.sources, s.video.hz, s.video.fps)
        if key != self._raw_key:
            self._raw, self._raw_key, self._polarity = {}, key, {}
        f = s.frames[frame]
        if f.source not in self._raw:
            footage = raw_frames(self._where(f.source), s.video)  # as the project samples them (a still: one)
            grey = np.stack([cv2.cvtColor(x, cv2.COLOR_RGB2GRAY) for x in footage.frames])
            self._raw[f.source] = (grey, np.asarray(footage.frame_index))
        grey, index = self._raw[f.source]
        hit = np.flatnonzero(index == f.source_frame)
        return grey[int(hit[0]) if len(hit) else 0]

    def _where(self, source: int) -> Path:
        """Where source ``source`` is on this machine (a ProjectError when it is missing)."""
        src = self.state.project.sources[source]
        where = locate(src, self.state.project.path)
        if where is None:
            raise ProjectError(f"source {source} is missing (it was at {src.absolute}): relink it above to preview it")
        return where

    def _box(self, grey: np.ndarray, source: int) -> tuple[int, int, int, int]:
        """The preview's square in source pixels: the project's frame (a still: the whole image, centred)."""
        box = self.state.project.sources[source].frame_box
        if box is None:
            h, wd = grey.shape
            side = max(h, wd)
            box = ((wd - side) // 2, (h - side) // 2, side, side)
        return box

    def polarity(self, source: int) -> str:
        """Source ``source``'s polarity as the project finds it: on all its sampled frames in source pixels."""
        if source not in self._polarity:
            cfg = self.state.project.state.still if self._is_still(source) else self.state.project.state.video
            self._polarity[source] = source_polarity(self._raw[source][0], cfg.polarity)
        return self._polarity[source]

    # ---------------------------------------------------------------- drawing
    def _scrubbed(self, change: dict) -> None:
        if change["new"] != self.state.selection.frame:  # set by redraw() to the frame selected: nothing to select
            self.state.select(frame=change["new"])

    def _changed(self, what: str) -> None:
        if what in ("project", "selection"):
            self.redraw()

    def redraw(self) -> None:
        """Show the project as it is now: sources, scrubber range, settings of the selected frame's source."""
        p = self.state.project
        n_of = [sum(f.source == i for f in p.frames) for i in range(len(p.sources))]
        rows = [
            f"{i}: {Path(s.path).name} ({s.kind}, {s.footage or '?'}, {count(n_of[i], 'frame')})"
            for i, s in enumerate(p.sources)
        ]
        if self.pending is not None:
            rows.append(f"waiting for its object in the first frame: {self.pending.name} (colour footage)")
        self.sources.value = "<br>".join(html.escape(r) for r in rows)  # a shared project's names are not markup
        self.relink.refresh()
        n = len(p.frames)
        self.scrubber.max = max(n - 1, 0)
        self.scrubber.value = frame_in_view(self.state)
        self.hz.value = p.state.video.hz
        if n:
            f = p.frames[frame_in_view(self.state)]
            self.frame_info.value = f"source {f.source}, source frame {f.source_frame}, {seconds(f.time_s)}"
            cfg = p.state.still if self._is_still(f.source) else p.state.video
            with self.threshold.hold_trait_notifications(), self.otsu.hold_trait_notifications():
                self.otsu.value = cfg.threshold is None
                if cfg.threshold is not None:
                    self.threshold.value = cfg.threshold
            self.pockets.value, self.pockets.disabled = p.state.still.pocket_reach > 0, not self._is_still(f.source)
            self._first_of(f.source)
        self.threshold.disabled = self.otsu.value
        self._throttled()  # drawn in the preview's own thread: a large photo's cleanup takes seconds

    def _show(self, rgb: np.ndarray) -> None:
        self.preview_rgb = rgb
        self.preview.value = png(rgb)

    def _first_changed(self, rgb: np.ndarray) -> None:
        """The first-frame picture changed (box typed, mask painted): it is what the panel previews."""
        if self.pending is not None:
            self.preview_rgb = rgb

    def _first_of(self, source: int) -> None:
        """Segmented footage selected (nothing pending): its first frame and box, to segment it again from."""
        src = self.state.project.sources[source]
        shown = self.pending is None and src.footage == "segmented"
        self.first.widget.layout.display = None if shown or self.pending is not None else "none"
        if not shown or self._first_source == (source, src.path, src.box):
            return
        self._first_source = (source, src.path, src.box)
        self.first.show(raw_frames(self._where(source), self.state.project.state.video).frames[0])
        if src.box is not None:
            for t, v in zip(self.box, src.box, strict=True):
                t.value = int(v)

    def _waiting(self, path: Path | None, first: np.ndarray | None = None) -> None:
        """Raw footage ``path`` with its ``first`` frame ``(H, W, 3)`` waits for its object (None: nothing waits): the
        first frame's picture replaces the preview while it does."""
        self.pending = path
        self.first.widget.layout.display = None if path is not None else "none"
        self.preview.layout.display = "none" if path is not None else None
        if path is not None:
            self.first.show(first)

    def refresh_preview(self) -> None:
        """Draw the binary mask at the slider's threshold (or Otsu's) over the selected frame, now (raw footage
        waiting for its object: its first frame with the box or the painted mask)."""
        with self._drawing:  # the slider's throttled draw runs on a timer thread (widgets.images.Throttle)
            self._draw_preview()

    def _draw_preview(self) -> None:
        self.threshold.disabled = self.otsu.value
        if self.pending is not None:
            self.first.redraw()
            return
        if not self.state.project.frames:
            return
        frame = frame_in_view(self.state)
        source = self._source_index()
        grey = self._raw_grey(frame)  # source pixels: the polarity and the levels are decided there (module doc)
        p = self.state.project
        cfg = p.state.still if self._is_still(source) else p.state.video
        src = p.sources[source]

        def threshold_alone(grey_sq: np.ndarray, level: float, mask: np.ndarray) -> None:  # shown before the cleanup
            self.preview_level, self.preview_mask = level, mask
            self._show(tint(grey_rgb(grey_sq), mask, MASK_RGB, 0.55))
            self.stored_info.value = f"<small>cleaning up at level {level:.0f}…</small>"  # a large photo: seconds

        shown = frame_preview(
            grey, self._box(grey, source), PREVIEW_PX, self.polarity(source),
            None if self.otsu.value else float(self.threshold.value), src.footage or "shadow", p.state.video,
            replace(p.state.still, pocket_reach=POCKET_REACH if self.pockets.value else 0.0),
            stored=p.state.targets[frame] if src.footage == "segmented" else None, first=threshold_alone,
        )  # fmt: skip
        self.stored_mask = shown.stored
        stored = shown.stored if shown.stored is not None else np.zeros_like(shown.mask)
        self.stored_rgb = tint(grey_rgb(shown.grey), stored, MASK_RGB, 0.55)
        self.stored.value = png(self.stored_rgb)
        level = f"at Otsu's level {shown.level:.0f}" if self.otsu.value else f"at level {shown.level:.0f}"
        reading = ("found " if cfg.polarity == "auto" else "") + POLARITY_WORDS[self.polarity(source)]
        self.stored_info.value = f"<small>{html.escape(shown.note or level)}; {reading}</small>"


def targets_panel(state: StudioState) -> w.Widget:
    """The Targets panel's widget (module doc)."""
    return TargetsPanel(state).widget
