"""The Rig panel: measure the rig (light, backdrop, mount, roll, foam) with a camera, and keep it in the calibration.

The notebook face of :func:`studio.project.rig_calibration.calibrate_rig` (the engine of ``calibrate-rig``).
**Show camera** grabs a frame (a device number, a video file or frame folder, or ``virtual``: the emulator's hand
photographed on a true-rig YAML's rig) and shows the window on it beside its rectified shadow (:class:`widgets.rig_view
.WindowView`: from the backdrop's markers, or four clicked corners). **Calibrate** starts from the studio's
calibration as it is then (:mod:`widgets.calibration_file`; one that cannot be read stops it), in a thread of its own
with progress and **Cancel**, on the Jog panel's connection when it is connected to the chosen servos (its e-stop
stops the run), else on a :class:`hardware.session.ServoSession` of its own, closed fail-safe (servos stopped, torque
held) however the run ends; its files go to ``rig-calibration/`` in the project's folder. **Save to calibration**
writes the measured rig to :func:`calibration_path`, atomically, only on that click. Errors are one line in the panel.
"""

from __future__ import annotations

import html
import logging
import tempfile
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass, field, replace
from pathlib import Path

import ipywidgets as w
import numpy as np

from hardware.calibration import Calibration, check_writable, save_calibration
from hardware.camera import Camera
from hardware.errors import EStopLatched
from hardware.estop import check_not_latched
from hardware.serial_bus import BusConfig
from hardware.session import CloseReport, ServoSession
from studio.errors import Cancelled, Progress, StudioError
from studio.project.capture import open_camera_source
from studio.project.rig_calibration import RigCalibration, RigCalibrationConfig, calibrate_rig
from studio.sim.hand import Hand, load_hand
from widgets.calibration_file import calibration_path, studio_calibration
from widgets.images import Messages, background, shown_when_drawn, title
from widgets.rig_view import WindowView, progress_line, summary_lines
from widgets.state import StudioState

log = logging.getLogger(__name__)


@dataclass
class RigPanelConfig:
    """How the Rig panel calibrates and draws."""

    calibration: RigCalibrationConfig = field(default_factory=RigCalibrationConfig)  # poses, capture, fit
    photo_px: int = 480  # width of the photograph on screen, px
    mask_px: int = 240  # side of the rectified shadow on screen, px
    redraw_hz: float = 10.0  # progress redraws a second at most, from the calibration's thread (0, 30]
    timeout_s: float | None = None  # s to wait for a servo's answer (None: 0.02 on a port, 0.2 on the emulator) (0, 10]


class RigPanel:
    """The Rig panel of one studio (module doc); ``.widget`` is what the notebook shows."""

    def __init__(self, state: StudioState, cfg: RigPanelConfig | None = None, hand: Hand | None = None):
        self.state = state
        self.cfg = cfg or RigPanelConfig()
        self.hand = hand or load_hand()
        self.messages = Messages()
        self.result: RigCalibration | None = None  # the last finished calibration
        self.last_close: CloseReport | None = None  # how the servos this panel opened were left
        self._borrowed = False  # the last run's servos were the Jog panel's (not closed by this panel)
        self._thread: threading.Thread | None = None
        self.showing: threading.Thread | None = None  # the "Show camera" button's grab, while it runs
        self._cancel = threading.Event()
        self._drawn = (0.0, "")  # (monotonic time, stage) of the last progress redraw
        self.cal = self._start_calibration()
        self._build()

    def _start_calibration(self) -> Calibration:
        return studio_calibration(self.state, self.hand, lambda text: self.messages.say(text, error=True))

    def _build(self) -> None:
        lay = w.Layout
        self.source = w.Text(description="camera", placeholder="0, a video file or frame folder, or virtual",
                             layout=lay(width="420px"))  # fmt: skip
        self.true_rig = w.Text(description="true rig", placeholder="RIG.yaml (the virtual camera's rig as it is)",
                               layout=lay(width="420px"), disabled=True)  # fmt: skip
        self.source.observe(lambda c: setattr(self.true_rig, "disabled", c["new"].strip() != "virtual"), "value")
        self.show_button = w.Button(description="Show camera", icon="camera")
        self.servos = w.ToggleButtons(options=[("emulator", "emulator"), ("serial port", "port")], value="emulator")
        self.port = w.Text(placeholder="/dev/ttyUSB0", description="port", layout=lay(width="260px"))
        res = self.cfg.calibration.capture.resolution
        self.view = WindowView(self.messages, self.cal.rig().window, res, self.cfg.photo_px, self.cfg.mask_px)
        self.poses = w.BoundedIntText(value=self.cfg.calibration.poses, min=3, max=200, description="poses",
                                      layout=lay(width="160px"))  # fmt: skip
        self.calibrate_button = w.Button(description="Calibrate", button_style="primary", icon="crosshairs")
        self.cancel_button = w.Button(description="Cancel", button_style="danger", icon="stop", disabled=True)
        self.progress = w.FloatProgress(value=0.0, min=0.0, max=1.0, description="idle")
        self.status, self.summary = w.Label(""), w.HTML("")
        self.compare = shown_when_drawn(w.Image(format="png", layout=lay(max_width="660px")))
        self.save_path = w.Text(value=str(calibration_path(self.state)), description="calibration",
                                layout=lay(width="520px"))  # fmt: skip
        self.save_button = w.Button(description="Save to calibration", icon="save", disabled=True)
        for button, act in ((self.show_button, self.show_camera_aside), (self.calibrate_button, self.calibrate),
                            (self.cancel_button, self.cancel), (self.save_button, self.save)):  # fmt: skip
            button.on_click(lambda _, act=act: act())
        self.widget = w.VBox([
            title("Rig"),
            w.HBox([self.source, self.show_button]), self.true_rig,
            w.HBox([w.Label("servos"), self.servos, self.port]),
            self.view.widget,
            w.HBox([self.poses, self.calibrate_button, self.cancel_button, self.progress, self.status]),
            self.summary, self.compare,
            w.HBox([self.save_path, self.save_button]),
            self.messages.widget,
        ])  # fmt: skip

    # ---------------------------------------------------------------- camera and servos
    def _servos(self, stack: ExitStack) -> ServoSession:
        """The Jog panel's session when it is connected to the chosen servos, else one of the panel's own, closed
        (servos stopped, torque held) when ``stack`` closes."""
        port = None if self.servos.value == "emulator" else self.port.value.strip()
        if port == "":
            raise ValueError("type the serial port of the servo adapter (e.g. /dev/ttyUSB0), or use the emulator")
        jog = getattr(self.state.extras.get("jog"), "session", None)
        self._borrowed = jog is not None and jog.is_open and (jog.emulator is not None if port is None else
                                                              jog.port == port)  # fmt: skip
        if self._borrowed:
            return jog  # the Jog panel's connection: its e-stop stops the calibration too
        config = BusConfig(port or "", timeout_s=self.cfg.timeout_s)
        session = ServoSession(port, calibration=self.cal, config=config).open()
        stack.callback(lambda: setattr(self, "last_close", session.close()))  # close() never raises
        return session

    def _camera(self, stack: ExitStack, session: ServoSession | None = None) -> Camera:
        """The camera the source box names, open (``virtual``: photographing ``session``'s emulator, by default
        :meth:`_servos`)."""
        source = self.source.value.strip()
        if not source:
            raise ValueError("type the camera: its number (0 for the first), a video file or frame folder, or virtual")
        if source != "virtual":
            return stack.enter_context(open_camera_source(source))
        if not self.true_rig.value.strip():
            raise ValueError("the virtual camera needs a true rig file (YAML): the rig as it really is")
        session = session or self._servos(stack)
        if session.emulator is None:
            raise ValueError("the virtual camera photographs the emulator's hand: choose the emulator servos")
        true_rig = Path(self.true_rig.value.strip()).expanduser()
        return stack.enter_context(open_camera_source(source, session.emulator, self.cal, true_rig, hand=self.hand))

    def show_camera(self) -> bool:
        """Grab one frame, find the backdrop's window in it and show both; whether a frame came."""
        return bool(self.messages.run(self._show_camera))

    def show_camera_aside(self) -> None:
        """ "Show camera": :meth:`show_camera` (never raises) in the panel's thread: a USB camera opens in seconds."""
        if not self.running and (self.showing is None or not self.showing.is_alive()):
            self.show_button.disabled = self.calibrate_button.disabled = True
            self.messages.say("opening the camera for one frame")
            self.showing = background(lambda: (self.show_camera(), self._busy(self.running)), "rig-show-camera")

    def _show_camera(self) -> bool:
        with ExitStack() as stack:
            photo = self._camera(stack).latest().image
        self.view.show(photo)
        return True

    # ---------------------------------------------------------------- calibrating (a thread of its own)
    @property
    def running(self) -> bool:
        """Whether a calibration runs now."""
        return self._thread is not None and self._thread.is_alive()

    def calibrate(self) -> bool:
        """Start a calibration in the background (module doc); whether it started."""
        if self.running:
            return False
        try:  # the servos are driven on the studio's calibration as it is now, never the shipped one in its place
            self.cal = studio_calibration(self.state, self.hand, strict=True)
        except StudioError as e:
            self.messages.say(f"could not calibrate: {e}", True)
            return False
        H = self.view.H if self.view.clicking else None
        if self.view.clicking and H is None:
            self.messages.say("click the window's four corners on the photograph first (or use the markers)", True)
            return False
        cfg = replace(self.cfg.calibration, poses=int(self.poses.value))
        self.result, self.summary.value, self.compare.value = None, "", b""
        self._cancel = threading.Event()
        self._busy(True)
        self.messages.say("calibrating: the hand moves through the calibration poses")
        self._thread = threading.Thread(target=self._run, args=(cfg, H, self._cancel), name="rig-calibration",
                                        daemon=True)  # fmt: skip
        self._thread.start()
        return True

    def _run(self, cfg: RigCalibrationConfig, H: np.ndarray | None, cancel: threading.Event) -> None:
        """The calibration's thread: servos, camera, engine, outcome; every end a line in the panel."""
        session: ServoSession | None = None
        try:
            check_not_latched("the servos")
            with ExitStack() as stack:  # the camera closes first, then the panel's own servos (stopped, held)
                session = self._servos(stack)
                camera = self._camera(stack, session)
                result = calibrate_rig(session.bus, self.cal, camera, cfg, out=self._out(), hand=self.hand,
                                       progress=self._progress, cancel=cancel, H_backdrop_camera=H)  # fmt: skip
            self._finished(result)
        except Cancelled:
            self._stopped(session, "calibration stopped: cancelled before the end")
        except (StudioError, ValueError, OSError) as e:  # the e-stop, a camera, the backdrop, the servos, a file
            how = "stopped" if isinstance(e, EStopLatched) else "failed"
            self._stopped(session, f"calibration {how}: {e}", error=True)
        except Exception as e:  # a bug: the servos stopped, a line in the panel, never a traceback
            log.debug("rig calibration failed", exc_info=True)
            self._stopped(session, f"calibration failed unexpectedly ({type(e).__name__}: {e})", error=True)
        finally:
            self._busy(False)

    def _out(self) -> Path:
        """A new folder for this run's files, ``rig-calibration/<date-time>-<random>`` in the project's folder."""
        (folder := self.state.project.path / "rig-calibration").mkdir(exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=time.strftime("%Y%m%d-%H%M%S-"), dir=folder))

    def _stopped(self, session: ServoSession | None, what: str, error: bool = False) -> None:
        """Say how a run ended early and how the servos were left (the Jog panel's are sent a stop)."""
        if session is None:
            left = "the servos were not opened"
        elif not self._borrowed:
            left = session.close().message  # closed already: how it was left
        else:
            try:
                session.bus.stop()
                left = "servos stopped (the Jog panel stays connected)"
            except Exception as e:  # the Jog panel's bus failed: it says so itself on its next move
                left = f"the stop did not reach the servos ({e}): cut their power if they still move"
        self.progress.description = "stopped"
        self.messages.say(f"{what}; {left}", error=error)

    def _progress(self, p: Progress) -> None:
        """A progress event from the engine (the calibration's thread): drawn at most ``redraw_hz`` a second."""
        now = time.monotonic()
        if p.stage == self._drawn[1] and p.step < p.total and now - self._drawn[0] < 1.0 / self.cfg.redraw_hz:
            return
        self._drawn = (now, p.stage)
        self.progress.description, self.progress.value = p.stage, p.fraction if p.total > 0 else 0.0
        self.status.value = progress_line(p)

    def _finished(self, result: RigCalibration) -> None:
        self.result = result
        self.progress.description, self.progress.value = "done", 1.0
        lines = summary_lines(result.summary)
        self.summary.value = "<br>".join(html.escape(x, quote=False) for x in lines)
        compare = result.files.get("compare")
        self.compare.value = compare.read_bytes() if compare is not None and compare.is_file() else b""
        self.messages.say(f"{lines[0]}. Press 'Save to calibration' to keep this rig in {self.save_path.value} "
                          f"(this run's files: {result.files['summary'].parent})")  # fmt: skip

    def _busy(self, running: bool) -> None:
        for b in (self.show_button, self.calibrate_button, self.view.clear_button, self.view.mode, self.poses):
            b.disabled = running
        self.cancel_button.disabled = not running
        self.save_button.disabled = running or self.result is None
        if running:
            self.progress.description, self.progress.value, self.status.value = "starting", 0.0, ""

    def cancel(self) -> bool:
        """Stop the calibration (between poses or fit steps; the servos are then stopped); whether one ran."""
        if not self.running:
            return False
        self._cancel.set()
        self.status.value = "stopping…"
        return True

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait for the calibration to end; whether it has."""
        if (t := self._thread) is not None:
            t.join(timeout_s)
        return not self.running

    def save(self) -> Path | None:
        """Write the calibration with the measured rig to the path in the box (atomically); where, or None."""
        return self.messages.run(self._save)

    def _save(self) -> Path:
        if self.result is None:
            raise ValueError("nothing to save yet: calibrate first")
        path = check_writable(Path(self.save_path.value.strip()).expanduser())
        existed = path.exists()
        save_calibration(self.result.calibration, path)
        self.state.extras["calibration_path"] = path
        self.state.changed("hardware")
        how = "it replaced the calibration there" if existed else "a new calibration file, beside the project's files"
        self.messages.say(f"saved the measured rig in {path} ({how})")
        return path

    def close(self) -> None:
        """Cancel a running calibration and wait for its servos to stop."""
        if self.cancel():
            self.wait(10.0)


def rig_panel(state: StudioState, cfg: RigPanelConfig | None = None) -> RigPanel:
    """The Rig panel (its widget is ``.widget``)."""
    return RigPanel(state, cfg)
