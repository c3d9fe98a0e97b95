"""The Jog panel: move the hand (or the built-in emulator) one joint at a time, read it back, e-stop it.

A face of :class:`hardware.jog.Jog` (DESIGN §5.7) on a :class:`hardware.session.ServoSession`: connect to the
emulator (21 virtual servos on a pseudo-terminal, started with the calibration's IDs, stopped on disconnect) or to
a serial port; a slider per joint spans that joint's soft limits in the studio's calibration
(:mod:`widgets.calibration_file`, read again at each connect and when the Rig panel saves) and moves its servo at
jog speed; read back the measured angles on demand or periodically (a background thread that only sets label
values, ≤ 10 Hz); torque on/off; home; the selected keyframe's pose, ramped; a large e-stop that latches the bus
(a separate reset clears it; the latch is shared with every process, :mod:`hardware.estop`). Failing safe (DESIGN
§5.13): every error becomes a message in the panel, never a traceback; a lost port disables the sliders; anything
unexpected sends a stop; a disconnect (the session's close) stops every servo and leaves torque held (or released,
``release_on_close``), as the message says.
"""

from __future__ import annotations

import html
import logging
import math
import threading
from dataclasses import dataclass, field, replace

import ipywidgets as W
import numpy as np

from hardware.calibration import Calibration
from hardware.errors import BusError
from hardware.jog import Jog, JogConfig
from hardware.serial_bus import BusConfig, SerialServoBus
from hardware.session import CloseReport, ServoSession
from studio.errors import StudioError
from studio.sim.hand import Hand, load_hand
from widgets.calibration_file import studio_calibration
from widgets.images import title
from widgets.jog_actions import JogActions
from widgets.sculpt import SculptView
from widgets.state import StudioState

log = logging.getLogger(__name__)
ESTOP_LATCHED_COLOUR = "#7a0010"  # the E-STOP button while the latch holds: solid dark red (unlatched: 'danger' red)


@dataclass
class JogPanelConfig:
    """How the jog panel talks to the servos."""

    jog: JogConfig = field(default_factory=JogConfig)  # step size, jog speed, e-stop torque
    refresh_hz: float = 4.0  # periodic read-back rate when "refresh" is ticked (capped at 10 Hz) (0, 10]
    timeout_s: float | None = None  # s to wait for a servo's answer (None: 0.02 on a port, 0.2 on the emulator) (0, 10]
    release_on_close: bool = False  # on disconnect: stop, then release torque (True) or hold the pose (False)


def _deg(x: float) -> str:
    return "?" if not math.isfinite(x) else f"{math.degrees(x):.1f}°"


def _span(lo_deg: float, hi_deg: float) -> str:
    """A joint's range as the slider beside it reads it: ``−60…0°``."""
    return f"{round(lo_deg)}…{round(hi_deg)}°".replace("-", "−")  # (round: an int, never "-0")


class JogPanel(JogActions):
    """The jog panel of one studio (``.widget``); ``state.extras["jog"]`` is this panel while it is open."""

    def __init__(self, state: StudioState, calibration: Calibration | None = None, config: JogPanelConfig | None = None,
                 hand: Hand | None = None):  # fmt: skip
        self.state = state
        self.hand = hand or load_hand()
        self._given = calibration  # a calibration given here is kept; else the studio's, read again at each connect
        unread: list[str] = []  # the studio's calibration file could not be read: said once the panel is built
        self.cal = calibration or studio_calibration(state, self.hand, unread.append)
        self.cfg = config or JogPanelConfig()
        self.session: ServoSession | None = None  # the servos this panel opened (None: not connected)
        self.jog: Jog | None = None
        self.torque_on: bool | None = None  # what this panel last set (None: as the servos came)
        self._quiet = False  # set while the panel itself moves sliders (no move is sent)
        self._refresh_stop = threading.Event()
        self._refresh_thread: threading.Thread | None = None
        self._build()
        self._stop_listening = state.on_change(self._on_change)
        state.extras["jog"] = self
        self._set_enabled(False)
        self._say("not connected: the sliders shape the shadow only; choose the emulator (virtual servos) or a serial "
                  "port, then press connect to move the hand")  # fmt: skip
        if unread:
            self._say(unread[0], error=True)

    # ------------------------------------------------------------------ widgets
    def _build(self) -> None:
        self.title = title("Jog")
        self.source = W.ToggleButtons(options=[("emulator", "emulator"), ("serial port", "port")], value="emulator")
        self.port = W.Text(placeholder="/dev/ttyUSB0", description="port", layout=W.Layout(width="260px"))
        self.connect_button = W.Button(description="connect", icon="plug")
        self.disconnect_button = W.Button(description="disconnect")
        self.message = W.HTML()
        self.sliders: list[W.FloatSlider] = []
        self.measured: list[W.Label] = []
        self.spans: list[W.Label] = []  # each joint's range, beside its slider
        rows = []
        for k, j in enumerate(self.cal.joints):
            lo, hi = math.degrees(j.lower), math.degrees(j.upper)
            s = W.FloatSlider(value=min(max(0.0, lo), hi), min=lo, max=hi, step=0.5, description=j.name,
                              continuous_update=False, readout_format=".1f", style={"description_width": "120px"},
                              layout=W.Layout(width="420px"))  # fmt: skip
            s.observe(lambda change, k=k: self._slid(k, change["new"]), names="value")
            m = W.Label("measured ?", layout=W.Layout(width="110px"))
            span = W.Label(_span(lo, hi), layout=W.Layout(width="90px"))  # a slider at an end of its joint's range
            self.sliders.append(s)
            self.measured.append(m)
            self.spans.append(span)
            rows.append(W.HBox([s, span, m]))
        self.read_button = W.Button(description="read back")
        self.auto = W.Checkbox(value=False, description="refresh", indent=False, layout=W.Layout(width="90px"))
        self.torque_on_button = W.Button(description="torque on")
        self.torque_off_button = W.Button(description="torque off")
        self.home_button = W.Button(description="home")
        self.keyframe_button = W.Button(description="go to keyframe", layout=W.Layout(width="160px"))
        self.estop_button = W.Button(description="E-STOP", button_style="danger", icon="stop",
                                     layout=W.Layout(width="220px", height="72px"))  # fmt: skip
        self.estop_button.style.font_size = "24px"
        self.estop_button.style.font_weight = "bold"
        self.reset_button = W.Button(description="reset e-stop")
        self.connect_button.on_click(lambda _: self.connect())
        self.disconnect_button.on_click(lambda _: self.disconnect())
        self.read_button.on_click(lambda _: self.read())
        self.auto.observe(lambda c: self._auto_refresh(bool(c["new"])), names="value")
        self.torque_on_button.on_click(lambda _: self.torque(True))
        self.torque_off_button.on_click(lambda _: self.torque(False))
        self.home_button.on_click(lambda _: self.home())
        self.keyframe_button.on_click(lambda _: self.go_keyframe())
        self.estop_button.on_click(lambda _: self.estop())
        self.reset_button.on_click(lambda _: self.reset())
        self.moves = [self.torque_on_button, self.home_button, self.keyframe_button]
        self.sculpt = SculptView(self.state, self.hand)  # the sliders' shadow beside the target, "save as keyframe"
        self.widget = W.VBox([
            self.title,
            W.HBox([self.source, self.port, self.connect_button, self.disconnect_button]),
            self.message,
            W.HBox([self.estop_button, W.VBox([self.reset_button, self.read_button, self.auto])]),
            W.HBox([self.torque_on_button, self.torque_off_button, self.home_button, self.keyframe_button]),
            W.HBox([W.VBox(rows), self.sculpt.widget]),
        ])  # fmt: skip

    def _say(self, text: str, error: bool = False) -> None:
        colour = "#b00020" if error else "inherit"
        self.message.value = f"<span style='color:{colour}'>{html.escape(text, quote=False)}</span>"

    def _set_enabled(self, connected: bool, latched: bool = False) -> None:
        for w in self.moves:
            w.disabled = not connected or latched
        for s in self.sliders:  # disconnected, they shape the shadow alone; latched, nothing moves
            s.disabled = latched
        for w in (self.read_button, self.auto, self.torque_off_button, self.reset_button, self.disconnect_button):
            w.disabled = not connected
        self.connect_button.disabled = connected
        self._estop_look(connected and latched)

    def _estop_look(self, latched: bool) -> None:
        """The E-STOP button says at a glance whether the latch holds: solid dark red, a lock and "LATCHED — reset"
        while it does; the plain red stop button while it does not."""
        b = self.estop_button
        b.description = "E-STOP LATCHED — reset" if latched else "E-STOP"
        b.icon = "lock" if latched else "stop"
        b.tooltip = "latched: nothing moves until you press reset e-stop" if latched else "halt every servo now"
        b.style.button_color = ESTOP_LATCHED_COLOUR if latched else None  # None: the 'danger' red
        b.style.font_size = "16px" if latched else "24px"

    def _show_target(self) -> None:
        """Sliders to the pose last commanded (unknown angles left where they are); sends nothing."""
        if self.jog is None:
            return
        self._quiet = True
        try:
            for s, x in zip(self.sliders, self.jog.target):
                if math.isfinite(x):
                    s.value = math.degrees(x)
        finally:
            self._quiet = False
        self.sculpt.command(self.commanded_pose())

    def _show_measured(self, q: np.ndarray) -> None:
        for label, x in zip(self.measured, q):
            label.value = f"measured {_deg(x)}"
        self.sculpt.measure(self._hand_order(q))

    def commanded_pose(self) -> np.ndarray:
        """``(21,)`` rad in the hand's joint order: what the sliders say."""
        return self._hand_order(np.radians([s.value for s in self.sliders]))

    def _hand_order(self, q: np.ndarray) -> np.ndarray:
        """Angles in the calibration's joint order → the hand's (the shadow's) order."""
        by_name = dict(zip(self.cal.joint_names, np.asarray(q, np.float64), strict=True))
        return np.array([by_name.get(n, 0.0) for n in self.hand.joint_names])

    # ------------------------------------------------------------------ connecting
    @property
    def bus(self) -> SerialServoBus | None:
        """The connected bus (None: not connected)."""
        session = self.session
        return session.bus if session is not None and session.is_open else None

    @property
    def emulator(self):
        """The ``hardware.emulator.ServoEmulator`` this panel started (None: a serial port, or not connected)."""
        session = self.session
        return session.emulator if session is not None else None

    def connect(self) -> bool:
        """Connect to the emulator (started now) or the port in the text box; returns whether it worked."""
        if self.jog is not None:
            self.disconnect()
        if not self._read_calibration("connect"):
            return False
        port = None
        if self.source.value != "emulator":
            port = self.port.value.strip()
            if not port:
                self._say("type the serial port of the servo adapter (e.g. /dev/ttyUSB0) first", error=True)
                return False
        try:
            config, release = BusConfig(port or "", timeout_s=self.cfg.timeout_s), self.cfg.release_on_close
            self.session = ServoSession(port, calibration=self.cal, config=config, release_on_close=release).open()
            home = np.clip(self.hand.rest_pose(), self.cal.lower, self.cal.upper)
            self.jog = Jog(self.bus, self.cal, config=replace(self.cfg.jog), home_pose=home)
        except (StudioError, ImportError, OSError) as e:
            self._close_hardware()
            self._say(f"could not connect: {e}", error=True)
            return False
        except Exception as e:  # a bug: nothing left open, a message, never a traceback
            log.debug("jog panel: connect failed", exc_info=True)
            self._close_hardware()
            self._say(f"could not connect: unexpected {type(e).__name__}: {e}", error=True)
            return False
        self.torque_on = None
        silent = [i for i, x in zip(self.cal.ids, self.jog.target) if not math.isfinite(x)]
        self._show_target()
        self._show_measured(self.jog.target)
        self._set_enabled(True, self.bus.estop_latched)
        what = "the emulator" if port is None else port
        note = f"; servos {silent} did not answer (check their cables)" if silent else ": every servo answered"
        if self.bus.estop_latched:  # pressed here before, in another panel or another process: it still holds
            note += f". {self.bus.latch_message()}: press reset e-stop to move them"
        self._say(f"connected to {what} ({len(self.cal.ids)} servos){note}", error=bool(silent) or "e-stop" in note)
        return True

    def disconnect(self) -> None:
        """Stop every servo, hold or release torque (``release_on_close``), close the port and the emulator."""
        if self.jog is None:
            return
        closed = self._close_hardware()
        self._set_enabled(False)
        torque = "released" if self.cfg.release_on_close else ("off" if self.torque_on is False else "held")
        if closed is not None and closed.stopped:
            self._say(f"disconnected: servos stopped, torque {torque}")
        else:
            self._say("disconnected, but the stop did not reach the servos: cut their power if they still move", True)

    def _close_hardware(self) -> CloseReport | None:
        """Stop the read-back thread, then close the session (servos stopped, torque as configured; never raises)."""
        self._refresh_stop.set()
        t, self._refresh_thread = self._refresh_thread, None
        if t is not None and t is not threading.current_thread():
            t.join(2.0)
        session, self.session, self.jog = self.session, None, None
        self.sculpt.measure(None)
        return session.close() if session is not None else None

    def _lost(self, e: BusError) -> None:
        """The port failed (unplugged, powered off, emulator gone): close it, disable the sliders, say so."""
        self._close_hardware()
        self._set_enabled(False)
        self.auto.value = False
        self._say(f"lost the servo bus: {e}. The sliders shape the shadow only until you connect again.", error=True)

    def close(self) -> None:
        """Disconnect (servos stopped) and stop listening to the studio."""
        self.disconnect()
        self._stop_listening()
        self.sculpt.close()
        if self.state.extras.get("jog") is self:
            del self.state.extras["jog"]

    def _slid(self, k: int, deg: float) -> None:
        if self._quiet:
            return
        if self.jog is not None:
            self.move(k, deg)
        self.sculpt.command(self.commanded_pose())  # connected or not, the shadow follows the sliders

    # ------------------------------------------------------------------ periodic read-back and the studio
    def _on_change(self, what: str) -> None:
        if what == "hardware" and self.jog is None:  # the Rig panel saved a calibration: the sliders' limits
            self._read_calibration("read the new calibration")
        if what in ("selection", "project"):
            self.sculpt.redraw()  # the target of the frame in view
            k = self.selected_keyframe()
            self.keyframe_button.description = "go to keyframe" if k is None else f"go to keyframe {k}"


def jog_panel(state: StudioState, calibration: Calibration | None = None, config: JogPanelConfig | None = None):
    """The Jog panel (its widget is ``.widget``; while open it is also ``state.extras["jog"]``)."""
    return JogPanel(state, calibration, config)
