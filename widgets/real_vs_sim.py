"""Real versus simulated, in the Export tab: play the show with a camera watching, then every keyframe's real shadow
beside its simulated shadow and its target, with the losses.

A face of :func:`studio.project.show_capture.play_with_camera` (``shadow-studio play --camera`` is the other): the
camera is a device index, a video file or frame folder, or ``virtual`` (the emulator's hand rendered on the rig of a
true rig file and photographed: for trying the loop without a rig). It plays where the Export panel plays (the
emulator, or the hand at its port: the Jog panel's bus when that is connected to the port, else servos opened for the
job and closed fail-safe when it ends), as a job on the project's queue, so the notebook never waits; stop cancels it
(the player stops within a tick). When it ends: the picture of ``real_vs_sim.png`` (target | captured | simulated |
overlay per keyframe) and the loss table; the Review panel's live recording, when open, gets the captures on
``show_time``. Every error is a line in the view, never a traceback; the words are the notebook's (no flags).
"""

from __future__ import annotations

import html
import logging
import math
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import ipywidgets as w

from hardware.calibration import Calibration
from hardware.player import Player, PlayerConfig
from hardware.session import ServoSession
from hardware.show_checks import check_mount, check_show_hand
from studio.jobs import Job, JobEvent, JobState
from studio.project.capture import open_camera_source
from studio.project.show_capture import ShowCaptureConfig, play_with_camera
from studio.project.show_capture_data import LOSSES, ShowCaptureResult, show_targets
from studio.sim.hand import Hand, load_hand
from widgets.calibration_file import calibration_path, studio_calibration
from widgets.images import Messages, png, shown_when_drawn
from widgets.state import StudioState
from widgets.words import seconds

log = logging.getLogger(__name__)

HEADS = ("keyframe", "time", "captured vs target", "simulated vs target", "captured vs simulated", "")


@dataclass
class RealVsSimConfig:
    """How the view plays and shows."""

    capture: ShowCaptureConfig | None = None  # how the keyframes are photographed (None: the defaults)
    tile: int = 160  # side of each picture in the rows, px [64, 512]
    redraw_hz: float = 10.0  # progress redraws per second at most, from the queue's thread (0, 30]


class RealVsSimView:
    """``widget``: camera and true rig boxes, play with camera and stop, then the rows and the loss table. ``export``:
    the Export panel (where the show plays, its player settings, the planned show)."""

    def __init__(self, state: StudioState, export: Any, cfg: RealVsSimConfig | None = None, hand: Hand | None = None):
        self.state, self.export = state, export
        self.cfg = cfg or RealVsSimConfig()
        self.hand = hand or load_hand()
        self.job: Job | None = None  # the last job this view started
        self.result: ShowCaptureResult | None = None  # what it gave
        self._session: ServoSession | None = None  # servos opened for the running job (closed when it ends)
        self._last_draw = 0.0
        self.messages = Messages()
        self.camera = w.Text(placeholder="0, a video file, or virtual", description="camera",
                             layout=w.Layout(width="300px"))  # fmt: skip
        self.true_rig = w.Text(placeholder="true rig YAML (virtual camera only)", description="true rig",
                               layout=w.Layout(width="380px"))  # fmt: skip
        self.play_button = w.Button(description="play with camera", icon="camera", button_style="info")
        self.stop_button = w.Button(description="stop", icon="stop", button_style="danger", disabled=True)
        self.status = w.Label("")
        self.image = shown_when_drawn(w.Image(format="png", layout=w.Layout(max_width="100%")))
        self.table = w.HTML()
        self.play_button.on_click(lambda _: self.play())
        self.stop_button.on_click(lambda _: self.stop())
        self.widget = w.VBox([
            w.HTML("<b>Real versus simulated</b>: play with a camera watching the backdrop"),
            w.HBox([self.camera, self.true_rig, self.play_button, self.stop_button]),
            self.status, self.messages.widget, self.image, self.table,
        ])  # fmt: skip
        self._unsubscribe = state.queue.subscribe(self._on_event)

    # ---------------------------------------------------------------- playing
    def play(self) -> Job | None:
        """Play the planned show with the camera in the box, as a job; None (and a message) when it cannot start."""
        return self.messages.run(self._play)

    def _play(self) -> Job:
        show = self.export.current_show()
        source, rig = self.camera.value.strip(), self.true_rig.value.strip()
        if not source:
            raise ValueError("type the camera: its number (0 for the first), a video file or frame folder, or virtual")
        virtual = source == "virtual"
        if virtual and not rig:
            raise ValueError("the virtual camera needs a true rig file: the rig as it really is, which it photographs")
        on_emulator = self.export.target.value == "emulator"
        if virtual and not on_emulator:
            raise ValueError("the virtual camera photographs the emulator's hand: play on the emulator")
        cal = studio_calibration(self.state, self.hand, strict=True)  # the artist's rig: its simulated shadows
        check_show_hand(show.hand_hash, self.hand)
        check_mount(show.roll, cal, calibration_path(self.state))
        targets = show_targets(show, self.state.project, Path(self.state.project.path).parent)
        player_cfg = self.export.cfg.player or PlayerConfig()
        bus = None if on_emulator else self._bus(player_cfg, cal)
        capture = self.cfg.capture or ShowCaptureConfig()
        true_rig = Path(rig).expanduser() if virtual else None

        def run(report, cancel) -> ShowCaptureResult:
            with ExitStack() as stack:
                servos, emulator = bus, None
                if servos is None:
                    session = stack.enter_context(
                        ServoSession(calibration=cal, release_on_close=not player_cfg.hold_torque_on_stop)
                    )
                    servos, emulator = session.bus, session.emulator  # fmt: skip
                camera = open_camera_source(source, emulator, cal, true_rig)
                stack.callback(camera.close)
                player = Player(servos, cal, player_cfg)
                return play_with_camera(player, show, camera, capture, targets, progress=report, cancel=cancel)

        job = Job("play", run, title=f"play {show.title} with camera")
        self.stop_button.disabled, self.status.value = False, f"{job.title}: queued"
        try:
            self.job = self.state.queue.submit(job)
        except BaseException:
            self._close_session()
            raise
        return job

    def _bus(self, player_cfg: PlayerConfig, cal: Calibration):
        """The bus at the Export panel's port: the Jog panel's when it is connected there, else one opened here on
        the studio's calibration ``cal``."""
        port = self.export.port.value.strip()
        if not port:
            raise ValueError("type the serial port of the servo adapter (e.g. /dev/ttyUSB0), or play on the emulator")
        jog = self.state.extras.get("jog")
        if jog is not None and jog.bus is not None and jog.bus.config.port == port:
            return jog.bus  # the Jog panel's: its e-stop stops the show
        self._session = ServoSession(port, calibration=cal, release_on_close=not player_cfg.hold_torque_on_stop).open()
        return self._session.bus

    def _close_session(self) -> None:
        session, self._session = self._session, None
        if session is not None:
            session.close()  # servos stopped, torque as the player's config says; never raises

    def stop(self) -> bool:
        """Cancel the running play (the show stops within a tick); whether there was one."""
        stopped = self.job is not None and not self.job.finished and self.job.cancel()
        if stopped:
            self.messages.say("stopping…")
        return bool(stopped)

    # ---------------------------------------------------------------- job events (the queue's thread)
    def _on_event(self, e: JobEvent) -> None:
        try:
            if self.job is None or e.job_id != self.job.id:
                return
            now = time.monotonic()
            if not e.final:
                if now - self._last_draw >= 1.0 / self.cfg.redraw_hz:
                    self._last_draw = now
                    self.status.value = f"{self.job.title}: {e.stage} {e.step}/{e.total}" if e.total else e.stage
                return
            self._finished(self.job, e)
        except Exception:  # a redraw must never disturb the queue; no traceback in the notebook
            log.debug("the real-vs-simulated view failed to draw a job event", exc_info=True)

    def _finished(self, job: Job, e: JobEvent) -> None:
        self._close_session()
        self.stop_button.disabled = True
        self.status.value = f"{job.title}: {e.state.value} after {seconds(e.elapsed, 1)}"
        if e.state == JobState.FAILED:
            self.messages.say(f"{job.title} failed: {e.error.message if e.error else 'unknown error'}", True)
            return
        if not isinstance(job.result, ShowCaptureResult):
            self.messages.say(f"{job.title} stopped before the camera saw anything")
            return
        self.show(job.result)

    def show(self, result: ShowCaptureResult) -> None:
        """Draw ``result``: the rows' picture, the loss table, how the show ended; log it to the Review panel's live
        recording when one is open."""
        self.result = result
        self.image.value = png(result.sheet(self.cfg.tile))
        self.table.value = loss_table(result)
        pb = result.playback
        said = f"played: {pb.message}" if pb.ok else f"the show stopped ({pb.reason.value}): {pb.message}"
        seen = sum(c.captured is not None for c in result.captures)
        said += f"; the camera saw {seen} of {len(result.captures)} keyframes"
        if result.camera_error:
            said += f" (the camera failed during the show: {result.camera_error})"
        self.messages.say(said, error=not pb.ok or bool(result.camera_error))
        self._to_review(result)

    def _to_review(self, result: ShowCaptureResult) -> None:
        review = self.state.extras.get("panels", {}).get("review")
        recording = getattr(review, "recording", None)
        if recording is None or recording.closed:
            return
        try:
            from studio.review.real_vs_sim_log import log_captures

            log_captures(recording.rec, result.captures)
            recording.flush()
        except Exception:  # the view's picture is what matters; the review is a bonus
            log.warning("the captures could not be logged to the review", exc_info=True)

    def close(self) -> None:
        """Stop listening; a play still running is cancelled and the servos opened for it closed."""
        self._unsubscribe()
        if self.job is not None and not self.job.finished:
            self.job.cancel()
            self.job.wait(2.0)
        self._close_session()


def loss_table(result: ShowCaptureResult) -> str:
    """The per-keyframe losses as an HTML table (``–`` where a loss was not computed)."""

    def cell(x: float | None) -> str:
        return "–" if x is None or not math.isfinite(x) else f"{x:.3f}"

    head = "".join(f"<th style='padding:0 8px'>{h}</th>" for h in HEADS)
    rows = []
    for c in result.captures:
        values = [f"k{c.index}", f"{c.show_t:.2f} s", *(cell(c.losses.get(k)) for k in LOSSES), html.escape(c.error)]
        rows.append("<tr>" + "".join(f"<td style='padding:0 8px'>{v}</td>" for v in values) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(rows)}</table>"


def real_vs_sim_view(state: StudioState, export: Any, cfg: RealVsSimConfig | None = None) -> RealVsSimView:
    """The view (its widget is ``.widget``), placed in the Export panel."""
    return RealVsSimView(state, export, cfg)
