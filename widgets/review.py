"""The Review panel: the Rerun viewer in the notebook following the project's recording live, the target vs its
shadow for the frame in view, and the meshcat scene of light, hand and backdrop.

    panel = ReviewPanel(state)       # panel.widget goes in the notebook; panel.close() stops the scene's server

The recording is a :class:`studio.review.recording.ProjectRecording`: written to ``NAME.rrd`` beside the project
folder ``NAME.shadow`` (open it in the standalone viewer with ``rerun NAME.rrd``) and, when the ``rerun-notebook``
package is installed, streamed live to the viewer embedded here (:class:`widgets.review_viewer.ViewerBox`: as wide as
the output area, a height control, offline, and a "follow" switch that moves its time with the selection, a running
job, the show player and a finished play). Its self-model view shows the shipped self-model's shadow of each
keyframe pose (the model the studio's jobs search, loaded once). The project is logged again after every edit, job
progress as it comes (the queue's events on ``opt_step``) and a finished play's commanded vs measured angles when it
ends. Without
``rerun-notebook`` the panel says how to install it and how to open the file instead. The meshcat scene
(:class:`studio.review.scene.ShadowScene`, framed on the light, the hand and the backdrop; its server starts in
a thread of the panel's, as the recording opens in another, so the studio opens without waiting) shows the pose of the
frame's keyframe (the rest pose before it has a result) as an offline snapshot, redrawn when the selection changes,
and the pose the show player plays (:meth:`ReviewPanel.follow_player`); :class:`widgets.scene_snapshot.SceneSnapshot`
swaps the snapshots in the browser only once the new one is drawn, so the scene never goes blank. The show
preview (:mod:`widgets.show_player`: source | target | the show's shadow played in the browser, and the strip of
every frame) and a frame picker select the frame in view in every tab.
"""

from __future__ import annotations

import html
import importlib.util
import logging
import threading
import time
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import ipywidgets as w
import numpy as np

from studio.errors import StudioError
from studio.project.outputs import self_model_predictor
from studio.review.recording import ProjectRecording
from studio.review.scene import ShadowScene
from widgets.frame_picker import frame_picker
from widgets.images import Messages, Throttle, background, frame_picture, mask_picture, title
from widgets.review_rig import ReviewRig
from widgets.review_viewer import ViewerBox, log_finished_play
from widgets.scene_snapshot import SceneSnapshot
from widgets.show_player import ShowPreviewPanel
from widgets.state import StudioState

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReviewConfig:
    """What the Review panel shows."""

    rrd: Path | None = None  # where the recording is written (None: NAME.rrd beside the project folder NAME.shadow)
    viewer: bool = True  # embed the Rerun viewer (when rerun-notebook is installed)
    viewer_height: int = 560  # px of the embedded Rerun viewer (its width is the output area's; a control resizes it)
    scene: bool = True  # show the meshcat scene (starts a local meshcat server, stopped by close())
    scene_height: int = 420  # px of the meshcat snapshot (as wide as the output area)
    follow_interval_s: float = 0.5  # s, the least time between two moves of the viewer or the scene while a job runs
    # or the show player plays
    image_px: int = 192  # side of the target and shadow images, px
    self_model: bool = True  # draw the self-model's shadow of every keyframe pose in the viewer (loads the shipped
    # self-model once, as the studio's jobs use it)


def notebook_viewer_missing() -> str | None:
    """Why the Rerun viewer cannot be embedded here (None: ``rerun_notebook`` is importable)."""
    if importlib.util.find_spec("rerun_notebook") is None:
        return "the Rerun viewer in the notebook needs the rerun-notebook package: pip install rerun-notebook"
    return None


class ReviewPanel(ReviewRig):
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
        self.viewer: w.Widget | None = None  # the Rerun viewer widget (inside viewer_controls.widget)
        self.viewer_controls: ViewerBox | None = None  # the viewer with its height control and "follow" switch
        self.self_model = None  # θ (K, 21) → the self-model's shadows (K, R, R) for the viewer (None: not drawn)
        self._unsubscribe = lambda: None
        self._edits = 0  # project changes heard so far (an edit undone returns the same state object: counted)
        self.opened = threading.Event()  # set once the recording, its viewer and the scene are open (or could not be)
        self.viewer_box = w.VBox([w.HTML("<i>opening the Rerun viewer (the first time in a session takes a few "
                                         "seconds; the other tabs work meanwhile)</i>")])  # fmt: skip
        side = self.cfg.image_px
        blank = mask_picture(None, side)  # until the frame is drawn (an empty image: a broken-picture icon)
        self.target_image = frame_picture(side, blank)
        self.shadow_image = frame_picture(side, blank)
        self.caption = w.HTML("")
        self.scene_view = SceneSnapshot(height=self.cfg.scene_height)  # the meshcat snapshot on show
        self.shown_frame: int | None = None  # the frame whose target and shadow are shown
        self.shown_shadow: np.ndarray | None = None  # that frame's keyframe's result shadow (None: no result yet)
        self.scene_pose: np.ndarray | None = None  # (21,) rad shown in the meshcat scene
        self._scene_drawn = 0.0  # monotonic time of the last snapshot drawn
        self.relogger = Throttle(self._relog_now, hz=4.0)  # the project logged again after an edit, in its thread
        self._opening = 2 if self.cfg.scene else 1  # threads still opening (the recording's, the scene's)
        background(self._open_recording, "review-open")  # seconds: in the background, so the studio opens at once
        self.rig_heading = w.HTML("<b>the rig</b>" + (" <i>(starting its 3-D scene)</i>" if self.cfg.scene else ""))
        if self.cfg.scene:  # its server starts in a second or two: in the background too
            background(self._open_scene, "review-scene")
        pictures = w.HBox([w.VBox([w.HTML("target"), self.target_image]),
                           w.VBox([w.HTML("shadow"), self.shadow_image])])  # fmt: skip
        self.frame_picker, self._stop_picker = frame_picker(state)  # selects the frame in view in every tab
        self.preview = ShowPreviewPanel(state)  # the show preview player and the frame strip (widgets.show_player)
        self.follow_player(self.preview.player)
        self.widget = w.VBox([
            title("Review"), self.viewer_box, self.preview.widget, self.frame_picker, self.caption, pictures,
            self.rig_heading, self.scene_view, self.messages.widget,
        ])  # fmt: skip
        self._stop = state.on_change(self._on_change)
        with self._lock:  # the scene may open meanwhile and draw the frame in view too
            self.show_frame()

    # ---------------------------------------------------------------- the recording
    def _open_recording(self) -> None:
        """The recording, the project logged in it and the viewer streaming it (the panel's opening thread: the
        self-model's and the viewer's code load for seconds); then published, under the lock, to the rest."""
        try:
            self._publish(*self._open())
        except Exception as e:  # never a traceback, never a panel stuck on "opening"
            log.warning("review: the recording could not be opened", exc_info=True)
            self.missing = self.missing or f"the recording could not be opened ({type(e).__name__}: {e})"
            self._show_viewer()
        finally:
            self._opened_one()

    def _opened_one(self) -> None:
        with self._lock:
            self._opening -= 1
            if self._opening == 0:
                self.opened.set()

    def _open(self) -> tuple:
        """(recording, viewer box, the project state logged, self-model) opened without the lock (None where none)."""
        serve = self.missing is None
        model = self.messages.run(self_model_predictor) if self.cfg.self_model else None  # None: the reason is said
        try:
            logged = self.state.project.state, self._edits  # what is logged next, and how many changes it follows
            recording = ProjectRecording(path=self.rrd, notebook=serve)
            recording.log_project(self.state.project, model)
            recording.flush()
            box = None
            if serve:
                box = ViewerBox(recording, self.state.queue, self.cfg.viewer_height, self.cfg.follow_interval_s)
        except (StudioError, OSError, RuntimeError) as e:
            self.missing = self.missing or str(e)
            log.warning("review: %s", e)
            return None, None, None, model
        return recording, box, logged, model

    def _publish(self, recording: ProjectRecording | None, box: ViewerBox | None, logged, model) -> None:
        with self._lock:
            self.self_model = model
            if self.closed:  # closed while it opened
                if recording is not None:
                    recording.close()
                return
            self.recording, self.viewer_controls = recording, box
            self.viewer = None if box is None else box.viewer
            queue = self.state.queue
            if recording is not None and queue is not None:  # job progress on opt_step, a finished play's angles
                stops = [
                    queue.subscribe(recording.job_progress(on_step=box and box.on_step)),
                    queue.subscribe(box.job_event if box else partial(log_finished_play, recording, queue)),
                ]
                self._unsubscribe = lambda: [stop() for stop in stops]
            state, edits = logged if logged is not None else (None, None)
            if recording is not None and (self.state.project.state is not state or self._edits != edits):
                self.relog()  # edited while it opened (an edit and its undo: the state it read, not the one logged)
            self._show_viewer()

    def _show_viewer(self) -> None:
        if self.viewer_controls is not None:
            self.viewer_box.children = (self.viewer_controls.widget,)
            return
        where = html.escape(str(self.rrd))
        self.viewer_box.children = (w.HTML(
            f"<div style='color:#a60'>{html.escape(self.missing or '')}<br>Meanwhile the recording is written to "
            f"<code>{where}</code>: open it in the standalone viewer with <code>rerun {where}</code> (it follows "
            "the project while this studio is open).</div>"
        ),)  # fmt: skip

    def _relog_now(self) -> None:
        with self._lock:
            if not self.closed:
                self.relog()

    def relog(self) -> None:
        """Log the project's current state to the recording again (after an edit or an applied result)."""
        if self.recording is not None and not self.recording.closed:
            self.messages.run(self.recording.log_project, self.state.project, self.self_model)
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
        if self.scene is not None:
            names = self.scene.hand.joint_names
            self.show_pose(self.scene.hand.rest_pose() if result is None else result.theta(names))

    def follow_player(self, player: w.Widget) -> None:
        """Follow the show player ``player`` (``self.preview.player``: ``index``, the preview frame in view, and
        ``playing``; the clock of ``self.preview.preview`` says the show time, project frame and pose of each): the
        viewer moves to its time on ``show_time`` (on ``frame``, when paused, before a show is planned) and the scene
        shows the pose played then, at most every ``follow_interval_s`` while it plays and at once when it stops."""
        player.observe(self._player_moved, names=["index", "playing"])

    def _player_moved(self, _change: dict) -> None:
        shown, player = self.preview.preview, self.preview.player  # the ShowPreview it plays (None: none yet)
        if shown is None or self.closed or not len(shown.clock.times):
            return
        clock, playing = shown.clock, bool(player.playing)
        k = max(0, min(int(player.index), len(clock.times) - 1))
        with self._lock:
            if self.viewer_controls is not None:
                if clock.planned:
                    self.viewer_controls.at_show_time(float(clock.times[k]), playing=playing)
                elif not playing:
                    self.viewer_controls.at_frame(int(clock.frame[k]))
            theta = np.asarray(clock.theta[k], dtype=float)
            soon = playing and time.monotonic() - self._scene_drawn < self.cfg.follow_interval_s
            if np.isfinite(theta).all() and not soon:
                self.show_pose(theta)

    def _on_change(self, what: str) -> None:
        with self._lock:
            if self.closed:
                return
            if what == "project":
                self._edits += 1
                self.relogger()  # in its thread: logging a long video's project takes a tenth of a second or more
            if what in ("project", "selection"):
                self.show_frame()
            if what == "selection" and self.viewer_controls is not None and self.shown_frame is not None:
                self.viewer_controls.at_frame(self.shown_frame)  # the viewer shows the frame selected

    def close(self) -> None:
        """Stop following the project, finish the recording and stop the meshcat server (idempotent; a recording
        still opening is closed as soon as it is open)."""
        self.relogger.settle(10.0)  # the last edit is in the file
        with self._lock:
            if self.closed:
                return
            self.closed = True
        self.relogger.close(wait_s=10.0)
        self._stop()
        self._stop_picker()
        self._unsubscribe()
        self.preview.close()
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
