"""The Review panel: the Rerun viewer in the notebook following the project's recording live, the target vs its
shadow for the frame in view, and the meshcat scene of light, hand and backdrop.

    panel = ReviewPanel(state)       # panel.widget goes in the notebook; panel.close() stops the scene's server

The recording is a :class:`studio.review.recording.ProjectRecording`: written to ``NAME.rrd`` beside the project
folder ``NAME.shadow`` (open it in the standalone viewer with ``rerun NAME.rrd``) and, when the ``rerun-notebook``
package is installed, served to the viewer embedded here (offline: ``studio.review`` sets
``RERUN_NOTEBOOK_ASSET=inline``). The project is logged again after every edit and job progress is logged as it
comes (the queue's events on ``opt_step``). Without ``rerun-notebook`` the panel says how to install it and how to
open the file instead. The meshcat scene (:class:`studio.review.scene.ShadowScene`) shows the pose of the frame's
keyframe (the rest pose before it has a result) as an offline snapshot, redrawn when the selection changes.
"""

from __future__ import annotations

import html
import importlib.util
import logging
import threading
from dataclasses import dataclass
from pathlib import Path

import ipywidgets as w
import numpy as np

from studio.errors import StudioError
from studio.review.recording import ProjectRecording
from studio.review.scene import ShadowScene
from widgets.images import Messages, title
from widgets.optimise import mask_picture
from widgets.state import StudioState

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReviewConfig:
    """What the Review panel shows."""

    rrd: Path | None = None  # where the recording is written (None: NAME.rrd beside the project folder NAME.shadow)
    viewer: bool = True  # embed the Rerun viewer (when rerun-notebook is installed)
    viewer_height: int = 480  # px of the embedded Rerun viewer
    scene: bool = True  # show the meshcat scene (starts a local meshcat server, stopped by close())
    scene_height: int = 360  # px of the meshcat snapshot
    image_px: int = 192  # side of the target and shadow images, px


def notebook_viewer_missing() -> str | None:
    """Why the Rerun viewer cannot be embedded here (None: ``rerun_notebook`` is importable)."""
    if importlib.util.find_spec("rerun_notebook") is None:
        return "the Rerun viewer in the notebook needs the rerun-notebook package: pip install rerun-notebook"
    return None


class ReviewPanel:
    """The Review panel (module doc) over ``state``; ``.widget`` is what the notebook shows."""

    def __init__(self, state: StudioState, cfg: ReviewConfig | None = None):
        self.state = state
        self.cfg = cfg or ReviewConfig()
        self.messages = Messages()
        self.closed = False
        self._lock = threading.RLock()  # one writer at a time: listeners may run on a job's thread (zmq is not safe)
        project = state.project
        self.rrd = Path(self.cfg.rrd) if self.cfg.rrd is not None else project.path.with_suffix(".rrd")
        self.missing = notebook_viewer_missing() if self.cfg.viewer else "the embedded viewer is off"
        self.recording: ProjectRecording | None = None
        self.scene: ShadowScene | None = None
        self.viewer: w.Widget | None = None
        self._unsubscribe = lambda: None
        self.viewer_box = w.VBox([])
        self.target_image = w.Image(format="png", width=self.cfg.image_px, height=self.cfg.image_px)
        self.shadow_image = w.Image(format="png", width=self.cfg.image_px, height=self.cfg.image_px)
        self.caption = w.HTML("")
        self.scene_html = w.HTML("")
        self.shown_frame: int | None = None  # the frame whose target and shadow are shown
        self.shown_shadow: np.ndarray | None = None  # that frame's keyframe's result shadow (None: no result yet)
        self.scene_pose: np.ndarray | None = None  # (21,) rad shown in the meshcat scene
        self._open_recording()
        if self.cfg.scene:
            self.scene = self.messages.run(ShadowScene)
        pictures = w.HBox([w.VBox([w.HTML("target"), self.target_image]),
                           w.VBox([w.HTML("shadow"), self.shadow_image])])  # fmt: skip
        self.widget = w.VBox([
            title("Review"), self.viewer_box, self.caption, pictures, w.HTML("<b>the rig</b>"), self.scene_html,
            self.messages.widget,
        ])  # fmt: skip
        self._stop = state.on_change(self._on_change)
        self.show_frame()

    # ---------------------------------------------------------------- the recording
    def _open_recording(self) -> None:
        serve = self.missing is None
        try:
            self.recording = ProjectRecording(path=self.rrd, notebook=serve)
            self.recording.log_project(self.state.project)
            self.recording.flush()
            if self.state.queue is not None:
                self._unsubscribe = self.state.queue.subscribe(self.recording.job_progress())
            if serve:
                self.viewer = self.recording.notebook_widget(height=self.cfg.viewer_height)
        except (StudioError, OSError, RuntimeError) as e:
            self.missing = self.missing or str(e)
            log.warning("review: %s", e)
        if self.viewer is not None:
            self.viewer_box.children = (self.viewer,)
            return
        where = html.escape(str(self.rrd))
        self.viewer_box.children = (w.HTML(
            f"<div style='color:#a60'>{html.escape(self.missing or '')}<br>Meanwhile the recording is written to "
            f"<code>{where}</code>: open it in the standalone viewer with <code>rerun {where}</code> (it follows "
            "the project while this studio is open).</div>"
        ),)  # fmt: skip

    def relog(self) -> None:
        """Log the project's current state to the recording again (after an edit or an applied result)."""
        if self.recording is not None and not self.recording.closed:
            self.messages.run(self.recording.log_project, self.state.project)
            self.recording.flush()

    # ---------------------------------------------------------------- the frame in view
    def show_frame(self) -> None:
        """The selected frame's target, its keyframe's shadow, and that pose in the meshcat scene."""
        p, px = self.state.project, self.cfg.image_px
        if not p.frames:
            return
        i = max(0, min(self.state.selection.frame, len(p.frames) - 1))
        k = p.keyframes[int(p.assignment()[i])].id if p.keyframes else None
        result = None if k is None else p.results.get(k)
        self.shown_frame = i
        self.target_image.value = mask_picture(p.state.targets[i], px)
        self.shown_shadow = None if result is None else np.asarray(result.shadow)
        self.shadow_image.value = mask_picture(self.shown_shadow, px)
        f = p.frames[i]
        state = "no result yet" if result is None else ("stale result" if p.is_stale(k) else f"loss {_total(result)}")
        self.caption.value = f"frame {i} (source {f.source}, {f.time_s:.2f} s), keyframe {k}: {state}"
        if self.scene is not None and not self.scene.closed:
            self.scene.set_roll(self.state.project.mount.roll)  # the hand as the show mounts it
            names = self.scene.hand.joint_names
            theta = self.scene.hand.rest_pose() if result is None else result.theta(names)
            if self.messages.run(self.scene.set_pose, theta) is not None:
                self.scene_pose = np.asarray(theta)
                self.scene_html.value = self.scene.render_static(height=self.cfg.scene_height).data

    def _on_change(self, what: str) -> None:
        with self._lock:
            if self.closed:
                return
            if what == "project":
                self.relog()
            if what in ("project", "selection"):
                self.show_frame()

    def close(self) -> None:
        """Stop following the project, finish the recording and stop the meshcat server (idempotent)."""
        with self._lock:
            if self.closed:
                return
            self.closed = True
        self._stop()
        self._unsubscribe()
        if self.recording is not None:
            self.recording.close()
        if self.scene is not None:
            self.scene.close()


def _total(result) -> str:
    value = dict(result.loss).get("total")
    return "?" if value is None else f"{float(value):.4f}"


def review_panel(state: StudioState, cfg: ReviewConfig | None = None) -> ReviewPanel:
    """The Review panel over ``state`` (its ``.widget`` is what the notebook shows)."""
    return ReviewPanel(state, cfg)
