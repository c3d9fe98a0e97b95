"""The Live panel: the hand casts the shadow an artist is making, as they make it.

The notebook face of :func:`studio.project.live.run_live` (``shadow-studio live`` is the other). The artist chooses
a camera (a device number, a video file or a frame folder played as a camera, looping if asked), the servos (the
emulator, or the hand at a serial port: the Jog panel's connection when it is connected to the same servos, else a
:class:`~hardware.session.ServoSession` of the panel's own, closed fail-safe however the session ends), the mount's
roll (default: the studio's calibration's, :mod:`widgets.calibration_file`, following the Rig panel's saves) and
whether to record. **Start** runs everything in a thread of its own
(:class:`widgets.live_runner.LiveRunner`, which the panel owns), saying what it does: the camera is tried first (a
bad source is one line, before any servo is opened), then the e-stop's latch, the self-model and its retrieval index
(built once per machine, with its progress), the servos, the session.
While it runs :class:`widgets.live_view.LiveView` shows camera | target | commanded shadow and a status line.
**Stop** ends it at the next tick (servos stopped, torque as configured, the thread joined); **E-STOP** latches the
bus's e-stop (for every process; with no servos open it latches the file) and halts every servo at once; **reset
e-stop** clears it. Each session leaves its playback log (and, when recording, ``live.rrd`` and ``keyframes.json``)
in a folder of its own under the record folder; the line that ends it says why it ended, how it went and where its
files are. Errors are one line in the panel, never a traceback. The engine is imported on the first Start (it loads
torch), so the studio opens without it.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import ipywidgets as w

from hardware.calibration import Calibration
from hardware.estop import clear_latch, is_latched, set_latch
from hardware.session import CloseReport, ServoSession
from studio.sim.hand import Hand, load_hand
from studio.sim.roll import wrap_deg
from widgets.calibration_file import studio_calibration
from widgets.images import Messages, title
from widgets.jog import ESTOP_LATCHED_COLOUR
from widgets.live_runner import Ask, LiveRunner
from widgets.live_view import LiveView
from widgets.state import StudioState

if TYPE_CHECKING:
    from studio.imitate.config import LivePoseConfig
    from studio.imitate.retrieval import RetrievalConfig
    from studio.project.live import LiveResult, LiveSession
    from studio.project.live_config import LiveConfig
    from studio.targets.live_target import LiveTargetConfig

BY = "the Live panel"  # what the e-stop's latch says pressed it


@dataclass
class LivePanelConfig:
    """How the Live panel runs a session and draws it."""

    live: LiveConfig | None = None  # the session (None: the defaults); its roll_deg is the roll box's
    pose: LivePoseConfig | None = None  # how a frame becomes a pose (None: the defaults)
    target: LiveTargetConfig | None = None  # how a frame becomes a target (None: the defaults)
    retrieval: RetrievalConfig | None = None  # the retrieval index (None: the searches' own, 200,000 poses)
    tile: int = 240  # side of each picture on screen, px [64, 1024]
    redraw_hz: float = 10.0  # picture redraws a second at most, from the session's threads (0, 10]
    timeout_s: float | None = None  # s to wait for a servo's answer (None: 0.02 on a port, 0.2 on the emulator) (0, 10]
    stop_wait_s: float = 3.0  # how long Stop waits for the session to end before it says "stopping…", s [0, 60]


class LivePanel:
    """The Live panel of one studio (module doc); ``.widget`` is what the notebook shows."""

    def __init__(self, state: StudioState, cfg: LivePanelConfig | None = None, hand: Hand | None = None):
        self.state = state
        self.cfg = cfg or LivePanelConfig()
        self.hand = hand or load_hand()
        self.messages = Messages()
        self.view = LiveView(self.cfg.tile, self.cfg.redraw_hz)
        self.runner = LiveRunner(self.messages, self.view, self.cfg, self._calibration, self._jog_servos, self._ended)
        self._thread: threading.Thread | None = None  # the session's (the runner's) thread
        self._build()
        self._estop_look(is_latched())
        self._stop_listening = state.on_change(self._on_change)

    def _calibrated_roll(self) -> float:
        """The roll box's start: the studio's calibration's recorded roll, degrees (0 when it records none)."""
        cal = self._calibration(quiet=True)
        return 0.0 if cal.roll is None else round(wrap_deg(math.degrees(cal.roll)), 2)

    def _on_change(self, what: str) -> None:
        """The Rig panel saved the studio's calibration: the roll box follows the roll it records (not mid-session)."""
        if what == "hardware" and not self.running:
            self.roll.value = self._calibrated_roll()

    def _build(self) -> None:
        lay = w.Layout
        roll = self._calibrated_roll()
        self.source = w.Text(value="0", description="camera", placeholder="0, a video file or a frame folder",
                             layout=lay(width="420px"))  # fmt: skip
        self.loop = w.Checkbox(value=False, description="loop a file", indent=False, layout=lay(width="110px"))
        self.servo_choice = w.ToggleButtons(options=[("emulator", "emulator"), ("serial port", "port")],
                                            value="emulator")  # fmt: skip
        self.port = w.Text(placeholder="/dev/ttyUSB0", description="port", layout=lay(width="260px"))
        self.roll = w.BoundedFloatText(value=roll, min=-180.0, max=180.0, step=0.5, description="roll °",
                                       layout=lay(width="170px"))  # fmt: skip
        self.record = w.Checkbox(value=False, description="record to folder", indent=False, layout=lay(width="140px"))
        self.folder = w.Text(value=str(Path(self.state.project.path) / "live"), layout=lay(width="420px"))
        self.start_button = w.Button(description="Start", button_style="primary", icon="play")
        self.stop_button = w.Button(description="Stop", icon="stop", disabled=True)
        self.estop_button = w.Button(description="E-STOP", button_style="danger", icon="stop",
                                     layout=lay(width="220px", height="60px"))  # fmt: skip
        self.estop_button.style.font_weight = "bold"
        self.reset_button = w.Button(description="reset e-stop")
        for button, act in ((self.start_button, self.start), (self.stop_button, self.stop),
                            (self.estop_button, self.estop), (self.reset_button, self.reset)):  # fmt: skip
            button.on_click(lambda _, act=act: act())
        self.inputs = [self.source, self.loop, self.servo_choice, self.port, self.roll, self.record, self.folder]
        self.widget = w.VBox([
            title("Live"),
            w.HBox([self.source, self.loop]),
            w.HBox([w.Label("servos"), self.servo_choice, self.port, self.roll]),
            w.HBox([self.record, self.folder]),
            w.HBox([self.start_button, self.stop_button, self.estop_button, self.reset_button]),
            self.messages.widget,
            self.view.widget,
        ])  # fmt: skip

    def _calibration(self, quiet: bool = False) -> Calibration:
        """The studio's calibration (:mod:`widgets.calibration_file`): for the session, a file that cannot be read
        raises (the runner says why); ``quiet`` (what the panel shows before): the shipped one instead."""
        return studio_calibration(self.state, self.hand, strict=not quiet)

    def _jog_servos(self) -> ServoSession | None:
        """The Jog panel's servo session, if it has one (the runner borrows it when it is open on the same servos)."""
        return getattr(self.state.extras.get("jog"), "session", None)

    def _estop_look(self, latched: bool) -> None:
        """The E-STOP button says whether the latch holds (as the Jog panel's does)."""
        b = self.estop_button
        b.description, b.icon = ("E-STOP LATCHED", "lock") if latched else ("E-STOP", "stop")
        b.tooltip = "latched: nothing moves until you press reset e-stop" if latched else "halt every servo now"
        b.style.button_color = ESTOP_LATCHED_COLOUR if latched else None

    def _busy(self, running: bool) -> None:
        for x in (*self.inputs, self.start_button, self.reset_button):
            x.disabled = running
        self.stop_button.disabled = not running

    def _ended(self) -> None:
        """A session has ended (the runner's thread, after its line): the E-STOP button and the inputs come back."""
        self._estop_look(is_latched())
        self._busy(False)

    # ---------------------------------------------------------------- what the runner keeps
    @property
    def result(self) -> LiveResult | None:
        """The last session's."""
        return self.runner.result

    @property
    def files(self) -> list[Path]:
        """What the last session wrote (its log first)."""
        return self.runner.files

    @property
    def live_session(self) -> LiveSession | None:
        """The engine's session while the hand moves."""
        return self.runner.live_session

    @property
    def last_close(self) -> CloseReport | None:
        """How the servos the panel opened for the last session were left (None: it opened none)."""
        return self.runner.last_close

    # ---------------------------------------------------------------- starting and stopping
    @property
    def running(self) -> bool:
        """Whether a session (or its start) runs now."""
        return self.runner.running

    def start(self) -> bool:
        """Start a session in the background (module doc); whether it started (else a line says why)."""
        if self.runner.running:
            return False
        ask = self.messages.run(self._ask)
        if ask is None:
            return False
        self._busy(True)
        self.messages.say("starting: opening the camera")
        self._thread = self.runner.start(ask)
        return True

    def _ask(self) -> Ask:
        source = self.source.value.strip()
        if not source:
            raise ValueError("type the camera: its number (0 for the first), a video file or a frame folder")
        if source == "virtual":
            raise ValueError("the virtual camera photographs the hand's own shadow, so it cannot lead it: use a "
                             "camera, a video file or a frame folder")  # fmt: skip
        port = None if self.servo_choice.value == "emulator" else self.port.value.strip()
        if port == "":
            raise ValueError("type the serial port of the servo adapter (e.g. /dev/ttyUSB0), or use the emulator")
        folder = Path(self.folder.value.strip() or Path(self.state.project.path) / "live").expanduser()
        if folder.exists() and not folder.is_dir():
            raise ValueError(f"the record folder is a file: {folder}; give a folder")
        return Ask(source, bool(self.loop.value), port, float(self.roll.value), bool(self.record.value), folder)

    def stop(self, wait_s: float | None = None) -> bool:
        """End the session at the next tick (servos stopped) and wait up to ``wait_s`` s (default the config's)
        for its thread; whether one ran."""
        if not self.runner.stop():
            return False
        self.wait(self.cfg.stop_wait_s if wait_s is None else wait_s)
        return True

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait for the session's thread to end; whether it has."""
        if (t := self._thread) is not None and t is not threading.current_thread():
            t.join(timeout_s)
        return self._thread is None or not self._thread.is_alive()

    def estop(self) -> bool:
        """Latch the e-stop and halt every servo now; nothing moves until reset. Whether the halt (or, with no
        servos open, the latch) took."""
        session = self.runner.servos
        try:
            if session is not None and session.is_open:
                reached = session.bus.estop(by=BY)  # never raises
            else:
                set_latch(BY)
                reached = True
        except OSError as e:
            self.messages.say(f"the e-stop could not be latched ({e}): cut the servos' power", error=True)
            return False
        self._estop_look(True)
        said = "every servo halted and latched" if reached else "latched; the halt did not reach the servos (cut power)"
        said = f"E-STOP: {said}"
        self.messages.say(f"{said}; nothing moves until you press reset e-stop", error=True)
        return reached

    def reset(self) -> bool:
        """Clear the e-stop (for every process); whether it was cleared."""

        def reset() -> bool:
            session = self.runner.servos
            if session is not None and session.is_open:
                session.bus.reset_estop()
            else:
                clear_latch()
            self._estop_look(False)
            self.messages.say("e-stop reset: Start moves the hand again")
            return True

        return bool(self.messages.run(reset))

    def close(self) -> None:
        """Stop a running session (servos stopped), wait for it, and let the self-model go."""
        self._stop_listening()
        self.stop(10.0)
        self.wait(10.0)
        self.view.end()
        self.runner.close()


def live_panel(state: StudioState, cfg: LivePanelConfig | None = None) -> LivePanel:
    """The Live panel (its widget is ``.widget``)."""
    return LivePanel(state, cfg)
