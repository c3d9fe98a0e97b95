"""A project's review as one Rerun recording, live and/or saved (DESIGN §2 "review", §5.6).

    with ProjectRecording(path="review.rrd", url=DEFAULT_VIEWER_URL) as review:   # a file and a running viewer
        review.log_project(project)                    # frames, masks, keyframes, results, the show, at once
        queue.subscribe(review.job_progress())         # a job's best loss and shadow on opt_step, as it runs
        play_on_emulator(show, on_sample=review.playback_hook(joint_names))   # servo angles as the show plays
        review.log_playback(result)                    # ... or afterwards, with show_time

Sinks, chosen when it is made (each gets everything logged after): ``path`` writes an ``.rrd`` that opens in the
standalone viewer (``rerun review.rrd``); ``url`` streams to a running viewer (``rerun`` listens on
:data:`DEFAULT_VIEWER_URL`); ``serve`` hosts a gRPC server on this machine that viewers connect to
(:attr:`ProjectRecording.server_url`, ``rerun --connect URL``), and ``notebook`` does the same for
:meth:`ProjectRecording.show_notebook`, the viewer in a notebook cell (:mod:`studio.review.notebook_viewer`: offline,
100 % wide, reading the live stream). The layout is :func:`~studio.review.blueprint
.project_blueprint`. Everything here takes plain data (arrays, a Show, results); :meth:`ProjectRecording.log_project`
reads a ``studio.project.Project`` by its public attributes (review never imports the project layer).
"""

from __future__ import annotations

import logging
import math
import socket
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

import numpy as np
import rerun as rr

from studio.errors import StudioError
from studio.motion.show import Show
from studio.review.blueprint import FRAME, LOSS_TAB, project_blueprint
from studio.review.frames import FramesLogged, KeyframeReview, log_frames
from studio.review.job_progress import JobProgressLog
from studio.review.notebook_viewer import DEFAULT_HEIGHT, NotebookViewerError, notebook_viewer
from studio.review.playback import PlaybackSampleLog, log_playback
from studio.review.rig3d import RigReview, ShowsLogged, log_mount, log_rig, log_show, urdf_tree
from studio.review.series import VersionedLog
from studio.review.show_frames import ShowFramesLogged, log_show_frames
from studio.sim.hand import Hand, load_hand
from studio.sim.roll import turn
from studio.sim.shadow import Rig

log = logging.getLogger(__name__)

APPLICATION = "shadow_studio"  # Rerun application id (the viewer keeps one layout per application)
DEFAULT_VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"  # where a viewer started with plain `rerun` listens

SelfModel = Callable[[np.ndarray], np.ndarray]  # theta (K, 21) rad → predicted shadows (K, R, R) in [0, 1]


class ReviewError(StudioError):
    """A review cannot be recorded or shown as asked (the message says what to do)."""


def _listening(url: str, timeout: float = 1.0) -> bool:
    """Whether something accepts connections at a ``rerun+http://HOST:PORT/proxy`` URL's host and port."""
    parsed = urlparse(url)
    default = 443 if parsed.scheme.endswith("https") else 9876
    try:
        with socket.create_connection((parsed.hostname or "127.0.0.1", parsed.port or default), timeout=timeout):
            return True
    except OSError:
        return False


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _SteppedJobProgress(JobProgressLog):
    """:class:`JobProgressLog` telling ``on_step(event, opt_step)`` where it drew a running event's progress (and
    where a job's final event left it)."""

    def __init__(self, rec: rr.RecordingStream, names: Mapping[int, str] | None, on_step):
        super().__init__(rec, names)
        self.on_step = on_step

    def __call__(self, event: Any) -> None:
        super().__call__(event)
        running = getattr(event.state, "value", event.state) == "running"
        drawn = running and (math.isfinite(event.best) or event.shadow is not None)
        if self.on_step is not None and (drawn or event.final):
            _, offset, step = self._at[event.job_id]  # (stage, its offset, its last step), as just logged
            self.on_step(event, offset + step)


class ProjectRecording:
    """One recording of a project's review (module doc). Close it (or use ``with``) to finish the file."""

    def __init__(
        self,
        path: str | Path | None = None,
        url: str | None = None,
        serve: bool = False,
        notebook: bool = False,
        hand: Hand | None = None,
        rig: Rig | None = None,
        cfg: RigReview | None = None,
        recording_id: str | None = None,
        timeline: str = FRAME,
        sources: bool = False,
        server_memory_limit: str = "1GiB",
        flush_timeout_s: float = 10.0,
    ):
        """``path``/``url``/``serve``/``notebook``: the sinks (at least one); ``hand``, ``rig``: what is drawn in 3D
        (default: the shipped hand, ``Rig()``); ``timeline``: the one the viewer opens on; ``sources``: show a
        view of the RGB source frames; ``server_memory_limit``: what a served stream keeps for late viewers;
        ``flush_timeout_s``: how long :meth:`flush` and :meth:`close` wait for a slow or vanished viewer."""
        self.hand = hand or load_hand()
        self.rig = rig or Rig()
        self.cfg = cfg or RigReview()
        self.path = None if path is None else Path(path)
        self.server_url: str | None = None
        self.flush_timeout_s = flush_timeout_s
        self.blueprint = project_blueprint(timeline, sources=sources)
        self._sources = sources
        self.plot_in_front = LOSS_TAB  # the plot tab of the layout sent last (front_plot)
        sinks: list[Any] = []
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            sinks.append(rr.FileSink(str(self.path)))
        if url is not None:
            if not _listening(url):  # rerun would wait 5 s to connect, then hang on every flush
                raise ReviewError(f"no Rerun viewer is listening at {url}: start one (`rerun` listens at "
                                  f"{DEFAULT_VIEWER_URL}), or record to a file only (path=...)")  # fmt: skip
            sinks.append(rr.GrpcSink(url))
        if serve or notebook:
            server = rr.GrpcServerSink("127.0.0.1", _free_port(), server_memory_limit=server_memory_limit)
            sinks.append(server)
            self.server_url = server.uri
        if not sinks:
            raise ReviewError("a review needs somewhere to go: give path= (an .rrd file), url= (a running viewer), "
                              "serve=True or notebook=True")  # fmt: skip
        self.rec = rr.RecordingStream(APPLICATION, recording_id=recording_id)
        self.rec.set_sinks(*sinks, default_blueprint=self.blueprint)
        self._tree = urdf_tree(self.hand)
        self._show_frames_logged = ShowFramesLogged()  # the frames' images on show_time (log_show_frames)
        self._shows_logged = ShowsLogged()  # the show logged last (log_show)
        self._frames_logged = FramesLogged()  # where the frames' keyframe images were logged (log_frames)
        self.versions = VersionedLog(self.rec)  # what is logged whole, each version replacing the last
        log_rig(self.rec, self.hand, self.rig, self.cfg)
        self.closed = False

    # ---------------------------------------------------------------- what is logged
    def log_frames(
        self,
        targets: np.ndarray,
        expressive: np.ndarray,
        keyframes: Sequence[KeyframeReview],
        sources: Sequence[np.ndarray | None] | None = None,
        times: np.ndarray | None = None,
        show_times: np.ndarray | None = None,
    ) -> np.ndarray:
        """Frames and keyframes on ``frame`` (:func:`studio.review.frames.log_frames`), their keyframe and loss
        series on ``show_time`` too given ``show_times (N,)`` s; the series replace those logged before. Returns
        the assignment."""
        return log_frames(self.rec, targets, expressive, keyframes, sources, times, self.hand, self.rig, self.cfg,
                          self.versions, show_times, self._frames_logged)  # fmt: skip

    def log_show(self, show: Show) -> np.ndarray:
        """The planned show on ``show_time`` (:func:`studio.review.rig3d.log_show`: logged once, replacing the last
        show logged); returns the backdrop shadows."""
        return log_show(self.rec, self.hand, self.rig, show, self.cfg, self._tree, versions=self.versions,
                        logged=self._shows_logged)  # fmt: skip

    def log_playback(self, result: Any, rate_hz: float | None = None) -> float:
        """A finished playback's commanded vs measured angles (:func:`studio.review.playback.log_playback`),
        replacing the last playback's."""
        return log_playback(self.rec, result, rate_hz, self.versions)

    def playback_hook(self, joint_names: Sequence[str] | None = None) -> PlaybackSampleLog:
        """The player's ``on_sample(t, commanded, measured)`` hook streaming here; ``joint_names``: the player's
        column order (its calibration's joint names; default the hand's)."""
        return PlaybackSampleLog(self.rec, joint_names or self.hand.joint_names)

    def job_progress(
        self, names: Mapping[int, str] | None = None, on_step: Callable[[Any, int], None] | None = None
    ) -> JobProgressLog:
        """A job-queue subscriber drawing each job's progress on ``opt_step`` (``queue.subscribe(...)``);
        ``on_step(event, step)`` is told the ``opt_step`` where a running event's loss or shadow was drawn, and where
        a job's final event left it (a viewer following the job moves there)."""
        return _SteppedJobProgress(self.rec, names, on_step)

    def log_project(
        self, project: Any, self_model: SelfModel | None = None, sources: Sequence[np.ndarray | None] | None = None
    ) -> np.ndarray:
        """A project's current state: every frame's target and expressive mask, its keyframes with their results
        (pose, rendered shadow, losses, stale or not) and the planned show, with every frame's images also on
        ``show_time`` where a current show plays it (:mod:`studio.review.show_frames`). ``project`` is a
        ``studio.project.Project`` (read through ``state.targets``, ``combined_masks()``, ``frames``,
        ``keyframes``, ``results``, ``is_stale(id)``, ``show``, ``frame_show_times()``); ``self_model`` predicts the
        self-model's shadows of the keyframes' poses (the upright hand's: they are turned by the mount roll here);
        ``sources``: every frame's RGB source image framed like its target (None for none). Returns the frames'
        assignment."""
        names = self.hand.joint_names
        roll = project.state.mount.roll
        if roll != self.rig.roll:  # the hand mounted as the project's show wants it
            self.rig = self.rig.with_roll(roll)
            log_mount(self.rec, self.hand, roll)
        results = project.results
        theta = {k: r.theta(names) for k, r in results.items()}
        predicted = {}
        if self_model is not None and theta:
            ids = list(theta)
            upright = np.asarray(self_model(np.stack([theta[k] for k in ids])))  # the self-model's: the upright hand's
            predicted = dict(zip(ids, turn(upright, roll)))  # as the rolled mount casts them (the roll law)
        keyframes = [
            KeyframeReview(
                id=kf.id, representative=kf.representative, members=tuple(kf.members), theta=theta.get(kf.id),
                shadow=None if kf.id not in results else results[kf.id].shadow, self_model=predicted.get(kf.id),
                loss=dict(results[kf.id].loss) if kf.id in results else {}, stale=project.is_stale(kf.id),
            )
            for kf in project.keyframes
        ]  # fmt: skip
        times = np.array([f.time_s for f in project.frames], dtype=float)
        targets, masks = project.state.targets, project.combined_masks()
        show_times = None if project.show is None else project.frame_show_times()  # None while the show is stale
        which = self.log_frames(targets, masks, keyframes, sources, times, show_times)
        if project.show is not None:
            self.log_show(project.show)
            if show_times is not None:
                log_show_frames(self.rec, targets, masks, keyframes, which, show_times, sources,
                                self._show_frames_logged)  # fmt: skip
        return which

    # ---------------------------------------------------------------- viewers and the end
    def front_plot(self, plot: str, timeline: str) -> bool:
        """Bring the plot tab ``plot`` (``blueprint.LOSS_TAB``, ``SERVO_TAB``) to the front of every viewer: the
        layout is sent again with it, on ``timeline``, unless the last one sent has it already (a layout sent
        replaces what the artist arranged, so it is sent only when the tab changes). True when it was sent."""
        if plot == self.plot_in_front or self.closed:
            return False
        self.rec.send_blueprint(project_blueprint(timeline, self._sources, plot), make_active=True,
                                make_default=False)  # fmt: skip
        self.plot_in_front = plot
        return True

    def notebook_widget(self, height: int = DEFAULT_HEIGHT, panels: Mapping[str, str] | None = None):
        """The live viewer as a widget to place in a notebook layout (made with ``notebook=True``; not displayed):
        :func:`studio.review.notebook_viewer.notebook_viewer` on this recording's stream, 100 % wide and ``height``
        px tall, offline. A ReviewError saying what to install when the rerun-notebook package is missing."""
        if self.server_url is None:
            raise ReviewError("this recording serves no viewer: make it with ProjectRecording(..., notebook=True)")
        try:
            return notebook_viewer(self.server_url, height=height, panels=panels)
        except NotebookViewerError as e:
            raise ReviewError(str(e)) from None

    def show_notebook(self, height: int = DEFAULT_HEIGHT):
        """Show the live viewer in this notebook cell (made with ``notebook=True``) and return its widget."""
        from IPython.display import display

        viewer = self.notebook_widget(height)
        display(viewer)
        return viewer

    def flush(self) -> bool:
        """Send everything logged so far to every sink, waiting at most ``flush_timeout_s``; False (and a warning)
        when a sink did not take it all in time (a viewer that went away)."""
        try:
            self.rec.flush(timeout_sec=self.flush_timeout_s)
            return True
        except Exception as e:  # rerun raises when the timeout passes
            log.warning("the review did not reach every sink within %.0f s: %s", self.flush_timeout_s, e)
            return False

    def close(self) -> None:
        """Flush and finish every sink (the ``.rrd`` gets its footer; a served stream stops). Idempotent."""
        if self.closed:
            return
        self.closed = True
        self.flush()
        self.rec.disconnect()
        if self.path is not None:
            log.info("review written to %s (open it with: rerun %s)", self.path, self.path)

    def __enter__(self) -> ProjectRecording:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
