"""The servo bus: the abstract :class:`ServoBus` (the pyserial one is ``hardware.serial_bus.SerialServoBus``).

A concrete bus supplies four primitives (``connect``, ``disconnect``, ``_transmit`` for commands no servo
answers, ``request`` for one question and its answer); everything else (batched position writes, torque, health
reads, scanning, the e-stop latch) is built on them here, once. Positions on this layer are raw servo units
(0..1000); radians live in ``hardware.calibration``.

Failing safe (DESIGN §5.13): :meth:`ServoBus.estop` latches: from then on every command that would make a servo
move is refused with :class:`EStopLatched` (MOVE_STOP and torque-off still go out) until
:meth:`ServoBus.reset_estop`. The check runs under the bus lock right before each write, so a motion write either
reached the wire before the e-stop's MOVE_STOP or never goes out. The latch is also a file (:mod:`hardware.estop`)
that every bus of every process reads before each motion write: an e-stop set anywhere holds everywhere until one
reset, wherever it is made (a reset made elsewhere also clears this bus's latch).
"""

from __future__ import annotations

import logging
import threading
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import TypeVar

from hardware import constants as C
from hardware import estop as latch_file
from hardware.errors import (
    BusError,
    ChecksumError,
    EStopLatched,
    EStopResetFailed,
    ProtocolError,
    ServoTimeout,
    UnexpectedReply,
)

log = logging.getLogger(__name__)

Request = tuple[int, C.Command, tuple[int, ...]]  # (servo id, command, parameter values)
T = TypeVar("T")


def move_requests(targets: Mapping[int, float], duration_s: float) -> list[Request]:
    """MOVE_TIME_WRITE requests for ``{id: units}``; positions rounded into 0..1000, time into 0..30000 ms."""
    ms = int(min(max(round(duration_s * 1000), 0), C.MAX_MOVE_TIME_MS))
    return [(i, C.MOVE_TIME_WRITE, (int(min(max(round(u), 0), C.POS_UNITS)), ms)) for i, u in targets.items()]


def is_motion(request: Request) -> bool:
    """True for a command that may make a servo move or push (torque on); MOVE_STOP and torque-off are not."""
    _, command, values = request
    if command.code == C.LOAD_OR_UNLOAD_WRITE.code:
        return bool(values and values[0])
    return command.code in C.MOTION_CODES


class ServoBus(ABC):
    """A bus of LX-15D servos. Use as a context manager; every method is safe to call from several threads."""

    batch_size: int = 7  # servos per batch of move commands (paper)
    batch_gap_s: float = 0.010  # pause between batches in :meth:`write_positions` (paper)
    label: str = "servo bus"  # how messages name this bus

    def __init__(self) -> None:
        self._lock = threading.RLock()  # one conversation on the wire at a time
        self._estop = threading.Event()  # this process's e-stop latch: set by estop(), cleared by a reset
        self._estop_shared = False  # the latch above is also the file's (a reset elsewhere clears both)

    @abstractmethod
    def connect(self) -> None:
        """Open the bus."""

    @abstractmethod
    def disconnect(self) -> None:
        """Close the bus (safe to call twice)."""

    @abstractmethod
    def _transmit(self, requests: Sequence[Request]) -> None:
        """Write commands that no servo answers, back to back in one write (called by :meth:`send` under the lock,
        after the e-stop check)."""

    @abstractmethod
    def request(self, servo_id: int, command: C.Command, *values: int) -> tuple[int, ...]:
        """Ask one servo; return its answer's values (raises ServoTimeout, ChecksumError or UnexpectedReply)."""

    def __enter__(self) -> ServoBus:
        self.connect()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            self.disconnect()
        except BusError as e:
            if exc is None:
                raise
            log.debug("closing %s failed too: %s", self.label, e)  # the error in flight says more

    def send(self, requests: Sequence[Request]) -> None:
        """Send commands that no servo answers, back to back in one write. Raises :class:`EStopLatched` (sending
        nothing) when the e-stop is latched and any of them would make a servo move."""
        with self._lock:
            if any(is_motion(r) for r in requests) and self.estop_latched:
                raise EStopLatched(self.latch_message())
            self._transmit(requests)

    # --- e-stop --------------------------------------------------------------------------------------------
    def estop(self, release_torque: bool = False, by: str = "an e-stop") -> bool:
        """Latch the e-stop and halt every servo now (MOVE_STOP broadcast, then torque off if ``release_torque``),
        then record the latch in its file (``by`` says what pressed it) so that every process refuses motion.

        Safe from any thread and never raises; from now on every motion command is refused until
        :meth:`reset_estop`. Returns whether the halt reached the bus (False: the port failed; cut the power)."""
        self._estop.set()
        log.info("e-stop latched on %s", self.label)
        reached = True
        try:
            self.stop()
            if release_torque:
                self.set_torque(False)
        except Exception as e:  # the latch holds whatever happens to the port
            log.error("e-stop latched but the halt did not reach %s (%s): cut the servos' power", self.label, e)
            reached = False
        try:
            latch_file.set_latch(f"{by} on {self.label}")
            self._estop_shared = True
        except OSError as e:  # this process still refuses motion; other processes cannot know
            log.error("the e-stop is latched in this process only: writing %s failed (%s)", latch_file.latch_path(), e)
        return reached

    def reset_estop(self) -> None:
        """Clear the e-stop latch, here and in its file (for every process): motion commands go out again.
        Raises :class:`EStopLatched` when the file cannot be removed (the latch then stays)."""
        try:
            cleared = latch_file.clear_latch()
        except OSError as e:
            raise EStopResetFailed(
                f"the e-stop could not be reset: removing {latch_file.latch_path()} failed ({e.strerror or e}); "
                "remove that file by hand"
            ) from e
        if self._estop.is_set() or cleared is not None:
            log.info("e-stop reset on %s", self.label)
        self._estop.clear()
        self._estop_shared = False

    def check_estop(self) -> bool:
        """Latch here and halt every servo when the latch file appeared (an e-stop pressed in another process)
        while this bus is not latched yet; returns whether it did. Never raises (a watcher thread calls it)."""
        if self._estop.is_set() or not latch_file.is_latched():
            return False
        self._estop.set()
        self._estop_shared = True
        log.info("e-stop latched elsewhere: halting %s", self.label)
        try:
            self.stop()
        except Exception as e:
            log.error("e-stop latched but the halt did not reach %s (%s): cut the servos' power", self.label, e)
        return True

    @property
    def estop_latched(self) -> bool:
        """True from :meth:`estop` (here, or in any process: the latch file) until :meth:`reset_estop`."""
        if self._estop.is_set():
            if self._estop_shared and not latch_file.is_latched():  # reset in another process
                self._estop.clear()
                self._estop_shared = False
                log.info("e-stop reset elsewhere: %s may move again", self.label)
                return False
            return True
        return latch_file.is_latched()

    def latch_message(self) -> str:
        """The one line that says the e-stop is latched, who set it, and that nothing moves until a reset."""
        return latch_file.latched_message(self.label)

    # --- motion --------------------------------------------------------------------------------------------
    def move_batch(self, targets: Mapping[int, float], duration_s: float) -> dict[int, int]:
        """One batch of moves in a single write, no pauses; returns ``{id: units}`` actually sent."""
        reqs = move_requests(targets, duration_s)
        self.send(reqs)
        return {i: v[0] for i, _, v in reqs}

    def write_positions(self, targets: Mapping[int, float], duration_s: float) -> dict[int, int]:
        """Move servos to ``{id: units}`` over ``duration_s``, ``batch_size`` per batch with ``batch_gap_s`` between
        batches (DESIGN §4). Returns ``{id: units}`` actually sent (rounded and clamped to 0..1000).

        An e-stop during the move wakes the pause and refuses every later batch: :class:`EStopLatched` is raised,
        its ``sent`` holding the batches that went out before."""
        items = list(targets.items())
        sent: dict[int, int] = {}
        for k in range(0, len(items), self.batch_size):
            if k:
                self._estop.wait(self.batch_gap_s)  # returns early on an e-stop; the next send refuses
            try:
                sent.update(self.move_batch(dict(items[k : k + self.batch_size]), duration_s))
            except EStopLatched as e:
                e.sent = sent
                raise
        return sent

    def stop(self, ids: Iterable[int] | None = None) -> None:
        """MOVE_STOP: servos halt where they are (``None`` = broadcast to all)."""
        targets = [C.BROADCAST_ID] if ids is None else list(ids)
        self.send([(i, C.MOVE_STOP, ()) for i in targets])

    def set_torque(self, on: bool, ids: Iterable[int] | None = None) -> None:
        """Load (``True``) or unload the motors (``None`` = broadcast to all)."""
        targets = [C.BROADCAST_ID] if ids is None else list(ids)
        self.send([(i, C.LOAD_OR_UNLOAD_WRITE, (int(on),)) for i in targets])

    # --- reads ---------------------------------------------------------------------------------------------
    def read_position(self, servo_id: int) -> int:
        """Encoder position, servo units."""
        return self.request(servo_id, C.POS_READ)[0]

    def read_positions(self, ids: Iterable[int]) -> dict[int, int]:
        """``{id: units}``; raises on the first servo that does not answer."""
        return {i: self.read_position(i) for i in ids}

    def read_back(self, ids: Iterable[int], read: Callable[[int], T] | None = None) -> dict[int, T | None]:
        """``{id: read(id)}`` for every servo in ``ids`` (default :meth:`read_position`, servo units); None for a
        servo that did not answer or answered garbled (after the bus's retries). A lost port still raises."""
        read = read or self.read_position
        out: dict[int, T | None] = {}
        for i in ids:
            try:
                out[i] = read(i)
            except (ServoTimeout, ProtocolError):
                out[i] = None
        return out

    def read_voltage(self, servo_id: int) -> float:
        """Supply voltage at the servo, V."""
        return self.request(servo_id, C.VIN_READ)[0] / 1000.0

    def read_temperature(self, servo_id: int) -> int:
        """Servo temperature, °C."""
        return self.request(servo_id, C.TEMP_READ)[0]

    def read_faults(self, servo_id: int) -> int:
        """Fault bits (``C.FAULT_*``); 0 when healthy."""
        return self.request(servo_id, C.LED_ERROR_READ)[0]

    def read_torque(self, servo_id: int) -> bool:
        return bool(self.request(servo_id, C.LOAD_OR_UNLOAD_READ)[0])

    def ping(self, servo_id: int) -> bool:
        """True when a servo answers ID_READ with its ID."""
        try:
            return self.request(servo_id, C.ID_READ)[0] == servo_id
        except ServoTimeout:
            return False


@dataclass
class ScanReport:
    """What answered on the bus."""

    present: list[int]  # IDs that answered cleanly
    duplicates: list[int]  # IDs whose answers collide (two servos share the ID)
    missing: list[int]  # IDs looked for (``expected``) that did not answer


def scan(bus: ServoBus, ids: Iterable[int], expected: Iterable[int] = ()) -> ScanReport:
    """Ping each ID; an ID whose position answers come back garbled on several tries is flagged as a duplicate
    (two servos answering at once on the open-drain wire AND their bytes together)."""
    present, dups = [], []
    for i in ids:
        try:
            answered = bus.request(i, C.ID_READ)[0] == i
        except ServoTimeout:
            continue
        except (ChecksumError, UnexpectedReply):
            answered = False
            dups.append(i)
            continue
        if not answered:
            continue
        garbled = 0
        for _ in range(2):
            try:
                for cmd in (C.POS_READ, C.VIN_READ, C.TEMP_READ):
                    bus.request(i, cmd)
            except (ChecksumError, UnexpectedReply, ServoTimeout):
                garbled += 1
        (dups if garbled == 2 else present).append(i)
    missing = [i for i in expected if i not in present and i not in dups]
    return ScanReport(present, dups, missing)
