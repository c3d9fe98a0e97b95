"""A project's show preview: every preview frame rendered once and encoded as JPEG for the Review panel's player,
and the strip of every frame (DESIGN §5.11: a background job with progress and cancel; plain data out).

    preview = render_preview(preview_inputs(project), PreviewConfig(), progress, cancel)
    queue.submit(preview_job(project, apply=show_it))      # the same, in the background on the project's queue
    strip, boxes = frame_strip(project)                    # target | shadow of every frame, each cell's box

What plays when is :mod:`.preview_clock`; the frames are :func:`studio.review.preview.render_frames`, the frames
``side_by_side.mp4`` is made of (source frame | target | the show's shadow, rendered with the rig as mounted). A
preview is named by :func:`preview_key`, the content hash of what it shows, so an unchanged project is never
rendered twice.

Measured on the 2 shared CPU cores of the development machine, 160 px columns, JPEG quality 85, 25 fps: the horse
clip (5 keyframes, a 1.9 s show after its late transitions were stretched, 64² masks) is 47 frames, 0.57 MB,
~0.15 s to render and encode (the renderer's first call in a process compiles for ~1 s more); a minute of show at
128² masks is 1,500 frames, 18 MB (~12 KB a frame), 3.7 s. The browser keeps them compressed and decodes ~2 s
ahead (widgets/show_player.js): 24–25 frames a second in headless Chromium for those 1,500 frames.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from studio.errors import ProgressFn, report
from studio.jobs.job import Job
from studio.project.inputs import show_inputs
from studio.project.preview_clock import PreviewInputs, preview_clock, preview_inputs
from studio.project.state import mask_hash, text_hash
from studio.review.preview import PreviewClock, render_frames
from studio.review.preview_strips import strip_image

__all__ = ["PreviewConfig", "PreviewInputs", "ShowPreview", "frame_strip", "preview_inputs", "preview_job",
           "preview_key", "render_preview"]  # fmt: skip


@dataclass(frozen=True)
class PreviewConfig:
    """How the show preview is rendered."""

    fps: float = 25.0  # preview frames per second of show time; the browser plays them at this rate × speed [20, 60]
    tile: int = 160  # side of each of the three columns, px [32, 512]
    quality: int = 85  # JPEG quality of the frames [10, 100]
    home: float | None = None  # rad/s: show the move from home before a show that starts with a still (None: not)

    def __post_init__(self) -> None:
        if not 20 <= self.fps <= 60 or not 32 <= self.tile <= 512 or not 10 <= self.quality <= 100:
            raise ValueError(f"a preview needs fps in [20, 60], tile in [32, 512] px, quality in [10, 100]: {self}")
        if self.home is not None and not self.home > 0:
            raise ValueError(f"the move from home needs a speed > 0 rad/s, not {self.home}")


@dataclass
class ShowPreview:
    """A rendered preview (plain data)."""

    key: str  # :func:`preview_key` of what it shows
    clock: PreviewClock  # what plays when: times, frames, poses, ticks, late transitions
    frames: list[bytes]  # M JPEG images (T, 3T + 8) RGB, one per preview time
    tile: int  # px, the side of each column
    seconds: float = 0.0  # wall time it took to render and encode

    @property
    def nbytes(self) -> int:
        """Bytes of all the encoded frames (what the browser receives)."""
        return sum(len(f) for f in self.frames)


def preview_key(inp: PreviewInputs, cfg: PreviewConfig) -> str:
    """The content hash of a preview of ``inp`` with ``cfg``: the show (samples, roll) and everything that shapes
    the frames (what a show is planned from, the masks as painted, the results' statuses, the sources' state)."""
    s, st = inp.state, inp.status
    show = None
    if s.show is not None:
        h = hashlib.sha256(np.ascontiguousarray(s.show.times, np.float64).tobytes())
        h.update(np.ascontiguousarray(s.show.positions, np.float64).tobytes())
        show = [h.hexdigest(), s.show.roll, list(s.show.joint_names)]
    return text_hash({
        "show": show, "inputs": show_inputs(s, inp.masks), "masks": mask_hash(inp.masks),
        "targets": mask_hash(s.targets), "roll": s.mount.roll, "missing": st.missing, "stale": st.stale,
        "show_stale": st.show_stale, "gone": [m.index for m in st.missing_sources], "cfg": dataclasses.asdict(cfg),
    })  # fmt: skip


def render_preview(
    inp: PreviewInputs,
    cfg: PreviewConfig | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    key: str | None = None,
) -> ShowPreview | None:
    """Render and encode every preview frame of the project ``inp`` (module doc). Progress: "sources" (reading
    the source frames), then "preview" m of M. Returns None when ``cancel`` is set (half a preview is not shown)."""
    from studio.project.sources import framed_frames

    cfg = cfg or PreviewConfig()
    t0 = time.perf_counter()
    s = inp.state
    clock = preview_clock(inp, cfg.fps, cfg.home)
    report(progress, "sources", 0, 1)
    sources = framed_frames(s.sources, s.frames, inp.path, s.video)
    report(progress, "sources", 1, 1)
    frames = render_frames(clock, sources, s.targets, inp.masks, s.mount.roll, cfg.tile, cfg.quality, progress,
                           cancel)  # fmt: skip
    if frames is None:
        return None
    return ShowPreview(key or preview_key(inp, cfg), clock, frames, cfg.tile, time.perf_counter() - t0)


def preview_job(project: Any, cfg: PreviewConfig | None = None, apply: Callable[[Any], None] | None = None) -> Job:
    """A background job (for the project's queue) rendering the preview of ``project`` as it is now →
    ``apply(ShowPreview)`` on completion; ``job.meta["key"]`` is its :func:`preview_key`."""
    cfg = cfg or PreviewConfig()
    inp = preview_inputs(project)
    key = preview_key(inp, cfg)
    run = functools.partial(_run_preview, inp=inp, cfg=cfg, key=key)
    return Job("preview", run, apply, "show preview", meta={"key": key})


def _run_preview(reporter, cancel, *, inp: PreviewInputs, cfg: PreviewConfig, key: str) -> ShowPreview | None:
    return render_preview(inp, cfg, reporter, cancel, key)


def strip_labels(project: Any) -> list[str]:
    """Each frame's label in the strip: ``#i`` and its keyframe's total loss, or why it has none."""
    status = project.status()
    out = []
    for i, pos in enumerate(project.assignment().tolist()):
        kf = project.keyframes[int(pos)]
        r = project.results.get(kf.id)
        total = None if r is None else dict(r.loss).get("total")
        if r is None:
            out.append(f"#{i} -")
        elif kf.id in status.stale:
            out.append(f"#{i} stale")
        else:
            out.append(f"#{i} {float(total):.3f}" if total is not None else f"#{i} ok")
    return out


def frame_strip(project: Any, tile: int = 64, columns: int = 8) -> tuple[np.ndarray, list[tuple[int, int, int, int]]]:
    """Every frame of ``project`` as ``target | shadow`` labelled with its keyframe's loss
    (:func:`~studio.review.preview_strips.strip_image`; the shadows of ``contact.png``: the pose the frame's keyframe
    plays, blank without a current result) → (RGB ``(H, W, 3)`` uint8, each frame's cell box ``(x, y, w, h)``)."""
    from studio.project.outputs import _frame_shadows  # contact.png's shadows: one way to say what a frame plays

    s = project.state
    return strip_image(s.targets, project.combined_masks(), list(_frame_shadows(project)), strip_labels(project),
                       tile, columns)  # fmt: skip
