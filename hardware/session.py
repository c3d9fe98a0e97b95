"""One way to reach the servos: :class:`ServoSession` opens the built-in emulator or a serial port, reads the
servos back, and closes fail-safe. The Jog panel, the Export panel's play button, the ``jog``/``play``/``scan``/
``calibrate`` verbs and :func:`hardware.dry_run.play_show` all open the servos through it::

    with ServoSession(calibration=cal) as s:                # port None: virtual servos on a pty (POSIX only)
        units = s.read_back()                               # {id: servo units}, None where a servo is silent
        Jog(s.bus, cal).go(0.3)
    with ServoSession("/dev/ttyUSB0", calibration=cal, release_on_close=True) as s:
        Player(s.bus, cal).play(...)

Failing safe (DESIGN §5.13): however a session ends (its ``with`` block returns or raises, :meth:`close` from any
thread, twice), it sends MOVE_STOP to every servo (a broadcast that goes out even while the e-stop is latched),
then torque off when ``release_on_close`` (else torque is left as the servos hold it), reads each servo's torque
back (which also waits until the stop has reached the servos, on the emulator before its thread ends), closes
the port and stops the emulator it started. :meth:`close` never raises: :class:`CloseReport` says what it managed
("unknown" torque when the bus failed: cut the servos' power). The e-stop is the bus's latch: a session neither
sets nor clears it, but while open it watches the latch's file (:mod:`hardware.estop`, every ``WATCH_S``) and halts
the servos as soon as an e-stop is pressed in another process (``shadow-studio estop``, another face), even while
this process waits for its user. A log (the player's) is written by whoever plays, inside the session, before it
closes.
"""

from __future__ import annotations

import importlib
import logging
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from types import ModuleType

from hardware.calibration import Calibration
from hardware.errors import BusError
from hardware.serial_bus import EMULATOR_TIMEOUT_S, BusConfig, SerialServoBus

log = logging.getLogger(__name__)

EMULATOR_IDS = tuple(range(1, 22))  # the emulator's servos when neither ids nor a calibration name them
WATCH_S = 0.05  # how often an open session looks for an e-stop pressed in another process, s


def load_emulator() -> ModuleType:
    """``hardware.emulator``, imported now (pty, termios: POSIX only); a :class:`BusError` saying so where this
    system lacks them."""
    try:
        return importlib.import_module("hardware.emulator")
    except ImportError as e:
        raise BusError(
            f"the servo emulator needs a POSIX system with pseudo-terminals (pty, termios), which this one lacks "
            f"({e}): use Linux or macOS, or a real servo adapter on a serial port"
        ) from None


@dataclass(frozen=True)
class CloseReport:
    """How a session ended."""

    stopped: bool  # MOVE_STOP (and the torque-off, when configured) reached the bus
    torque: str  # "held" (left as the servos had it), "released" (off), "unknown" (the bus failed while stopping)
    message: str  # one sentence for the user
    torque_on: dict[int, bool] = field(default_factory=dict)  # {id: torque on} read back after the stop


class ServoSession:
    """The servos on ``port`` (``None``: the built-in emulator, started with ``ids``), opened by :meth:`open` or a
    ``with`` block, which gives the session itself: :attr:`bus` is the connected
    :class:`~hardware.serial_bus.SerialServoBus`, :attr:`emulator` the ``ServoEmulator`` it started (or None);
    after :meth:`close` the emulator stays, stopped, so that its servos' state can still be read.

    ``ids``: the servos this session reads back and checks on close (default: the calibration's; on the emulator,
    1..21 when neither names them). ``config``: the link's settings (timeout, retries, echo, batching), its
    ``port`` replaced by ``port`` or the emulator's. ``release_on_close``: torque off after the closing stop
    (default False: the hand holds its pose, as the player's and the jog's defaults do). Thread-safe; opening an
    open session and closing a closed one do nothing; a closed session cannot be opened again.
    """

    def __init__(
        self,
        port: str | None = None,
        *,
        calibration: Calibration | None = None,
        ids: Iterable[int] | None = None,
        config: BusConfig | None = None,
        release_on_close: bool = False,
    ):
        if port is not None and not port.strip():
            raise BusError(
                "no serial port given: give the servo adapter's path (e.g. /dev/ttyUSB0) or use the emulator"
            )
        self.port = port
        self.calibration = calibration
        if ids is not None:
            self.ids = list(ids)
        else:
            self.ids = calibration.ids if calibration is not None else list(EMULATOR_IDS if port is None else ())
        self.config = config or BusConfig(port or "")
        self.release_on_close = release_on_close
        self.where = "the servo emulator" if port is None else f"servo bus {port!r}"  # how messages name it
        self.emulator = None  # the ServoEmulator open() started (None: a port); kept, stopped, after close
        self.report: CloseReport | None = None  # set by close()
        self._bus: SerialServoBus | None = None
        self._lock = threading.RLock()
        self._unwatch = threading.Event()  # set by close(): the e-stop watcher ends
        self._watcher: threading.Thread | None = None

    # --- lifecycle -------------------------------------------------------------------------------------------
    def open(self) -> ServoSession:
        """Start the emulator (when ``port`` is None) and open the port; returns the session. Raises
        :class:`BusError` in one line when the port is absent, busy or not allowed, or the emulator cannot run;
        whatever it started is undone then."""
        with self._lock:
            if self._bus is not None:
                return self
            if self.report is not None:
                raise BusError(f"this session on {self.where} was closed: open a new one")
            emulator = None
            try:
                if self.port is None:
                    em = load_emulator()
                    emulator = em.ServoEmulator(self.ids, em.EmulatorConfig(echo=self.config.echo)).start()
                timeout = self.config.timeout_s
                if timeout is None and emulator is not None:  # its servos answer from a thread beside the jobs
                    timeout = EMULATOR_TIMEOUT_S
                bus = SerialServoBus(replace(self.config, port=self.port or emulator.port, timeout_s=timeout))
                bus.connect()
            except BaseException:
                if emulator is not None:
                    emulator.stop()
                raise
            self.emulator, self._bus = emulator, bus
            self._watcher = threading.Thread(target=self._watch, args=(bus,), name="estop-watch", daemon=True)
            self._watcher.start()
            log.debug("servo session open on %s", bus.config.port)
        return self

    def _watch(self, bus: SerialServoBus) -> None:
        """Until close: halt the servos when an e-stop is latched in another process (its file appears)."""
        while not self._unwatch.wait(WATCH_S):
            bus.check_estop()  # never raises

    def close(self) -> CloseReport:
        """Stop every servo, set torque as configured, read it back, close the port and the emulator. Never raises
        (Ctrl-C during it still closes the port, then surfaces); safe from any thread and twice."""
        with self._lock:
            if self.report is not None:
                return self.report
            bus, emulator, self._bus = self._bus, self.emulator, None
            self._unwatch.set()
            watcher, self._watcher = self._watcher, None
            if watcher is not None and watcher is not threading.current_thread():
                watcher.join(1.0)
            if bus is None:
                report = CloseReport(False, "unknown", f"the session on {self.where} was never opened: nothing sent")
            else:  # what stands if the halt itself is interrupted (Ctrl-C)
                report = CloseReport(False, "unknown", f"closing {self.where} was interrupted: cut the servos' power")
            try:
                if bus is not None:
                    report = self._halt(bus)
            finally:
                self.report = report
                if bus is not None:
                    try:
                        bus.disconnect()
                    except BusError as e:
                        log.debug("closing %s failed too: %s", bus.label, e)
                if emulator is not None:
                    emulator.stop()
            return report

    def _halt(self, bus: SerialServoBus) -> CloseReport:
        """The closing stop: MOVE_STOP broadcast, torque off if configured, torque read back (also a barrier)."""
        try:
            bus.stop()
            if self.release_on_close:
                bus.set_torque(False)
        except Exception as e:  # best effort: the port and the emulator are closed next regardless
            message = f"the stop did not reach the servos on {self.where} ({e}): cut their power if they still move"
            log.debug(message)
            return CloseReport(False, "unknown", message)
        torque = "released" if self.release_on_close else "held"
        try:
            read = bus.read_back(self.ids, bus.read_torque)
        except Exception as e:  # the stop went out; only the check failed
            log.debug("reading the torque back from %s failed: %s", bus.label, e)
            read = {}
        on = {i: v for i, v in read.items() if v is not None}
        still = sorted(i for i, v in on.items() if v) if self.release_on_close else []
        if still:
            torque = "unknown"
            return CloseReport(True, torque, f"servos stopped, but {still} still hold torque: cut their power", on)
        return CloseReport(True, torque, f"servos stopped, torque {torque}", on)

    def __enter__(self) -> ServoSession:
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    # --- use -------------------------------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._bus is not None

    @property
    def bus(self) -> SerialServoBus:
        """The connected bus; :class:`BusError` before :meth:`open` or after :meth:`close`."""
        bus = self._bus
        if bus is None:
            state = "was closed: open a new one" if self.report is not None else "is not open yet: call open()"
            raise BusError(f"the servo session on {self.where} {state}")
        return bus

    def read_back(self) -> dict[int, int | None]:
        """``{id: servo units}`` of :attr:`ids` now; None for a servo that did not answer (a lost port raises)."""
        return self.bus.read_back(self.ids)
