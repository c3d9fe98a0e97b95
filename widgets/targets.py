"""The Targets panel: sources (a bundled sample, a file path or an upload), a frame scrubber, the sampling rate, the
threshold (or Otsu) with a live preview of the binary mask over the frame, and segmentation of raw colour footage
from a first-frame box, run as a job on the project's queue.

    panel = TargetsPanel(state)      # panel.widget goes in the notebook; tests set values and .click() buttons

The preview is the threshold alone on the frame's shadowness (inside the project's square frame); the project's
cleanup (components, holes, lines) applies when the threshold is applied.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import ipywidgets as w
import numpy as np
from studio.assets import asset

from studio.jobs import Job
from studio.project.sources import locate, source_kind
from studio.project.state import ProjectError
from studio.targets.images import read_grey, shadowness
from studio.targets.video import crop_square, read_frames
from widgets.images import MASK_RGB, Messages, Throttle, frame_in_view, grey_rgb, png, tint, title
from widgets.state import StudioState

log = logging.getLogger(__name__)

PREVIEW_PX = 256  # side of the preview image, px
UPLOADS = "uploads"  # folder inside the project where uploaded files are written


def bundled_samples() -> dict[str, Path]:
    """The shipped stills and videos: name → path."""
    found: dict[str, Path] = {}
    for folder in (Path(asset("targets/asl_o.jpeg")).parent, Path(asset("videos/muybridge_horse.gif")).parent):
        for p in sorted(folder.iterdir()):
            if p.suffix.lower() in (".jpeg", ".jpg", ".png", ".gif", ".mp4", ".avi", ".mov"):
                found[p.name] = p
    return found


class TargetsPanel:
    """The Targets panel (module doc) over ``state``; ``.widget`` is what the notebook shows."""

    def __init__(self, state: StudioState):
        self.state = state
        self.messages = Messages()
        self._raw: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # source → (grey frames (N, H, W), source indices)
        self._raw_key: object = None
        self.pending: Path | None = None  # raw colour footage waiting for a first-frame box
        self.preview_level = float("nan")  # the threshold the preview used (Otsu's when Otsu is on)
        self.preview_mask: np.ndarray | None = None  # (PREVIEW_PX, PREVIEW_PX) uint8 {0, 1}: the previewed mask
        self.segment_job: Job | None = None  # the last segmentation job
        self.preview_rgb: np.ndarray | None = None  # (PREVIEW_PX, PREVIEW_PX, 3) uint8: what the preview shows
        self._first: tuple[Path, np.ndarray] | None = None  # the pending footage's first frame (H, W, 3) RGB

        samples = bundled_samples()
        self.sample = w.Dropdown(options=list(samples), description="sample")
        self._samples = samples
        self.add_sample = w.Button(description="Add sample", icon="plus")
        self.path = w.Text(placeholder="a still, a video or a folder of frames", description="file")
        self.add_path = w.Button(description="Add file", icon="plus")
        self.upload = w.FileUpload(accept="image/*,video/*,.gif", multiple=False, description="Upload")
        self.sources = w.HTML()
        self.scrubber = w.IntSlider(min=0, max=0, description="frame", continuous_update=True)
        self.frame_info = w.Label()
        self.preview = w.Image(format="png", width=PREVIEW_PX, height=PREVIEW_PX)
        self.hz = w.BoundedFloatText(min=0.1, max=60.0, step=0.5, description="sampling Hz")
        self.apply_hz = w.Button(description="Apply sampling")
        self.threshold = w.FloatSlider(min=0.0, max=254.0, step=1.0, description="threshold", continuous_update=True)
        self.otsu = w.Checkbox(description="Otsu")
        self.apply_threshold = w.Button(description="Apply threshold")
        self.box = [w.IntText(description=n, layout=w.Layout(width="140px")) for n in ("x", "y", "w", "h")]
        self.segment = w.Button(description="Segment", icon="scissors")
        self.cancel_segment = w.Button(description="Cancel", icon="stop", disabled=True)
        self.segment_info = w.Label()

        self.add_sample.on_click(lambda _: self.messages.run(self._add, self._samples[self.sample.value]))
        self.add_path.on_click(lambda _: self.messages.run(self._add, Path(self.path.value.strip()).expanduser()))
        self.upload.observe(lambda ch: self.messages.run(self._uploaded, ch["new"]), names="value")
        self.scrubber.observe(lambda ch: self.state.select(frame=ch["new"]), names="value")
        self.apply_hz.on_click(lambda _: self.messages.run(self.state.edit, "set_sampling", hz=float(self.hz.value)))
        self._throttled = Throttle(self.refresh_preview, hz=15.0)
        self.threshold.observe(lambda _: self._throttled(), names="value")
        self.otsu.observe(lambda _: self._throttled(), names="value")
        self.apply_threshold.on_click(lambda _: self.messages.run(self._apply_threshold))
        self.segment.on_click(lambda _: self.messages.run(self._segment))
        for t in self.box:
            t.observe(lambda _: self._throttled(), names="value")
        self.cancel_segment.on_click(lambda _: self.segment_job is not None and self.segment_job.cancel())

        self.widget = w.VBox([
            title("Targets"),
            self.sources,
            w.HBox([self.sample, self.add_sample]),
            w.HBox([self.path, self.add_path, self.upload]),
            w.HBox([self.scrubber, self.frame_info]),
            self.preview,
            w.HBox([self.threshold, self.otsu, self.apply_threshold]),
            w.HBox([self.hz, self.apply_hz]),
            w.HTML("<i>raw colour footage: the shape's box on the first frame (source pixels)</i>"),
            w.HBox([*self.box, self.segment, self.cancel_segment]),
            self.segment_info,
            self.messages.widget,
        ])  # fmt: skip
        self._stops = [
            state.on_change(self._changed),
            state.queue.subscribe(self._job_event),  # the queue's thread writes only segment_info / messages
        ]
        self.redraw()

    def close(self) -> None:
        """Stop following the state (the widget stays as it is)."""
        for stop in self._stops:
            stop()

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
            self._raw, self._raw_key = {}, key
        f = s.frames[frame]
        if f.source not in self._raw:
            src = s.sources[f.source]
            where = locate(src, self.state.project.path)
            if where is None:
                raise ProjectError(f"source {f.source} is missing (it was at {src.absolute}): relink it")
            if src.kind == "still":
                self._raw[f.source] = (read_grey(where)[None], np.zeros(1, np.int64))
            else:
                rgb, _, index, _ = read_frames(where, s.video)
                grey = np.stack([cv2.cvtColor(x, cv2.COLOR_RGB2GRAY) for x in rgb])
                self._raw[f.source] = (grey, np.asarray(index))
        grey, index = self._raw[f.source]
        hit = np.flatnonzero(index == f.source_frame)
        return grey[int(hit[0]) if len(hit) else 0]

    def _square(self, grey: np.ndarray, source: int) -> np.ndarray:
        box = self.state.project.sources[source].frame_box
        if box is None:  # a still: the whole image, centred in a square
            h, wd = grey.shape
            side = max(h, wd)
            box = ((wd - side) // 2, (h - side) // 2, side, side)
        return np.clip(crop_square(grey, box, PREVIEW_PX), 0, 255).astype(np.uint8)

    # ---------------------------------------------------------------- drawing
    def _changed(self, what: str) -> None:
        if what in ("project", "selection"):
            self.redraw()

    def redraw(self) -> None:
        """Show the project as it is now: sources, scrubber range, settings of the selected frame's source."""
        p = self.state.project
        rows = [
            f"{i}: {Path(s.path).name} ({s.kind}, {s.footage or '?'}, {sum(f.source == i for f in p.frames)} frames)"
            for i, s in enumerate(p.sources)
        ]
        if self.pending is not None:
            rows.append(f"waiting for a first-frame box: {self.pending.name} (colour footage)")
        self.sources.value = "<br>".join(rows)
        n = len(p.frames)
        self.scrubber.max = max(n - 1, 0)
        self.scrubber.value = frame_in_view(self.state)
        self.hz.value = p.state.video.hz
        if n:
            f = p.frames[frame_in_view(self.state)]
            self.frame_info.value = f"source {f.source}, source frame {f.source_frame}, {f.time_s:.2f} s"
            cfg = p.state.still if self._is_still(f.source) else p.state.video
            with self.threshold.hold_trait_notifications(), self.otsu.hold_trait_notifications():
                self.otsu.value = cfg.threshold is None
                if cfg.threshold is not None:
                    self.threshold.value = cfg.threshold
            src = p.sources[f.source]
            if src.box is not None:
                for t, v in zip(self.box, src.box, strict=True):
                    t.value = int(v)
        self.threshold.disabled = self.otsu.value
        self.messages.run(self.refresh_preview, clear=False)

    def _pending_first(self) -> np.ndarray:
        if self._first is None or self._first[0] != self.pending:
            rgb, _, _, _ = read_frames(self.pending, self.state.project.state.video)
            self._first = (self.pending, rgb[0])
        return self._first[1]

    def _show(self, rgb: np.ndarray) -> None:
        self.preview_rgb = rgb
        self.preview.value = png(rgb)

    def _preview_box(self) -> None:
        """The pending footage's first frame with the box drawn on it (source pixels → the preview square)."""
        first = self._pending_first()
        h, wd = first.shape[:2]
        side = max(h, wd)
        scale = PREVIEW_PX / side
        square = np.clip(crop_square(first, (0, 0, side, side), PREVIEW_PX), 0, 255).astype(np.uint8)
        x, y, bw, bh = (int(t.value) for t in self.box)
        p0 = (int(round(x * scale)), int(round(y * scale)))
        p1 = (int(round((x + bw) * scale)) - 1, int(round((y + bh) * scale)) - 1)
        cv2.rectangle(square, p0, p1, MASK_RGB, 2)
        self._show(square)

    def refresh_preview(self) -> None:
        """Draw the binary mask at the slider's threshold (or Otsu's) over the selected frame, now (raw footage
        waiting for a box: its first frame with the box)."""
        self.threshold.disabled = self.otsu.value
        if self.pending is not None:
            self._preview_box()
            return
        if not self.state.project.frames:
            return
        frame = frame_in_view(self.state)
        source = self._source_index()
        grey = self._square(self._raw_grey(frame), source)
        cfg = self.state.project.state.still if self._is_still(source) else self.state.project.state.video
        shade = shadowness(grey, cfg.polarity)
        if self.otsu.value:
            level, _ = cv2.threshold(shade, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        else:
            level = float(self.threshold.value)
        mask = (shade > level).astype(np.uint8)
        self.preview_level, self.preview_mask = float(level), mask
        self._show(tint(grey_rgb(grey), mask, MASK_RGB, 0.55))

    def _job_event(self, event) -> None:
        job = self.segment_job
        if job is None or event.job_id != job.id:
            return
        if not event.final:
            counted = f" {event.step}/{event.total}" if event.total else ""
            self.segment_info.value = f"{job.title}: {event.stage}{counted}"
            return
        self.cancel_segment.disabled = True
        self.segment_info.value = f"{job.title}: {event.state.value}"
        if event.error is not None:
            self.messages.say(f"segmentation failed: {event.error}", error=True)

    # ---------------------------------------------------------------- actions
    def _add(self, path: Path) -> None:
        if not path.exists():
            raise ProjectError(f"no such file or folder: {path} (give a still, a video or a folder of frames)")
        try:
            index = self.state.edit("add_source", path)
        except ProjectError as e:
            if "colour footage" not in str(e):
                raise
            self.pending = path
            h, wd = self._pending_first().shape[:2]
            for t, v in zip(self.box, (wd // 4, h // 4, wd // 2, h // 2), strict=True):
                t.value = v  # a first guess: the middle of the frame
            self.redraw()
            self.messages.say(f"{path.name} is colour footage: give the shape's box on its first frame, then Segment")
            return
        self.pending = None
        first = next(i for i, f in enumerate(self.state.project.frames) if f.source == index)
        self.state.select(frame=first)

    def _uploaded(self, value) -> None:
        if not value:
            return
        item = value[0]
        name = Path(str(item["name"])).name
        if source_kind(name) not in ("still", "video"):
            raise ProjectError(f"{name} is neither a still nor a video (upload a .jpeg, .png, .gif or .mp4)")
        folder = self.state.project.path / UPLOADS
        folder.mkdir(exist_ok=True)
        out = folder / name
        out.write_bytes(bytes(item["content"]))
        log.info("uploaded %s (%d bytes)", out, out.stat().st_size)
        self._add(out)

    def _apply_threshold(self) -> None:
        level = None if self.otsu.value else float(self.threshold.value)
        if self._is_still(self._source_index()):
            self.state.edit("set_threshold", still=level)
        else:
            self.state.edit("set_threshold", video=level)

    def _segment(self) -> Job:
        box = tuple(int(t.value) for t in self.box)
        if box[2] <= 0 or box[3] <= 0:
            raise ProjectError(f"the first-frame box needs a width and a height above 0, not {box[2]} × {box[3]}")
        project, pending = self.state.project, self.pending
        if pending is None and self._is_still(self._source_index()):
            raise ProjectError("the selected frame is a still: segmentation is for colour footage")
        source = self._source_index()

        def run(report, cancel) -> int:
            def progress(stage: str, step: int, total: int) -> None:
                report(stage, step, total)
                report.check()

            if pending is not None:
                return project.add_source(pending, box=box, progress=progress)
            project.set_segmentation(source, box=box, progress=progress)
            return source

        def apply(index: int) -> None:
            if pending is not None and self.pending == pending:
                self.pending = None
            self.state.changed("project")

        what = pending.name if pending is not None else f"source {source}"
        job = Job("segment", run, apply=apply, title=f"segment {what}")
        self.segment_job = job
        self.cancel_segment.disabled = False
        self.state.queue.submit(job)
        self.segment_info.value = f"segmenting {what} (job {job.id})"
        self.state.changed("jobs")
        return job


def targets_panel(state: StudioState) -> w.Widget:
    """The Targets panel's widget (module doc)."""
    return TargetsPanel(state).widget
