"""The servo bus: an abstract :class:`ServoBus` and :class:`SerialServoBus`, pyserial on a half-duplex adapter.

A concrete bus supplies four primitives (``connect``, ``disconnect``, ``send`` for commands no servo answers,
``request`` for one question and its answer); everything else (batched position writes, torque, health reads,
scanning) is built on them here, once. Positions on this layer are raw servo units (0..1000); radians live in
``hardware.calibration``.
"""

from __future__ import annotations

import logging
import threading
import time
from abc import ABC, abstractmethod
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

from hardware import constants as C
from hardware.errors import BusError, ChecksumError, HardwareError, ServoTimeout, UnexpectedReply
from hardware.protocol import StreamDecoder, encode_request

log = logging.getLogger(__name__)

Request = tuple[int, C.Command, tuple[int, ...]]  # (servo id, command, parameter values)


def move_requests(targets: Mapping[int, float], duration_s: float) -> list[Request]:
    """MOVE_TIME_WRITE requests for ``{id: units}``; positions rounded into 0..1000, time into 0..30000 ms."""
    ms = int(min(max(round(duration_s * 1000), 0), C.MAX_MOVE_TIME_MS))
    return [(i, C.MOVE_TIME_WRITE, (int(min(max(round(u), 0), C.POS_UNITS)), ms)) for i, u in targets.items()]


class ServoBus(ABC):
    """A bus of LX-15D servos. Use as a context manager; every method is safe to call from several threads."""

    batch_size: int = 7  # servos per batch of move commands (paper)
    batch_gap_s: float = 0.010  # pause between batches in :meth:`write_positions` (paper)

    @abstractmethod
    def connect(self) -> None:
        """Open the bus."""

    @abstractmethod
    def disconnect(self) -> None:
        """Close the bus (safe to call twice)."""

    @abstractmethod
    def send(self, requests: Sequence[Request]) -> None:
        """Send commands that no servo answers, back to back in one write."""

    @abstractmethod
    def request(self, servo_id: int, command: C.Command, *values: int) -> tuple[int, ...]:
        """Ask one servo; return its answer's values (raises ServoTimeout, ChecksumError or UnexpectedReply)."""

    def __enter__(self) -> ServoBus:
        self.connect()
        return self

    def __exit__(self, *exc) -> None:
        self.disconnect()

    # --- motion --------------------------------------------------------------------------------------------
    def move_batch(self, targets: Mapping[int, float], duration_s: float) -> dict[int, int]:
        """One batch of moves in a single write, no pauses; returns ``{id: units}`` actually sent."""
        reqs = move_requests(targets, duration_s)
        self.send(reqs)
        return {i: v[0] for i, _, v in reqs}

    def write_positions(self, targets: Mapping[int, float], duration_s: float) -> dict[int, int]:
        """Move servos to ``{id: units}`` over ``duration_s``, ``batch_size`` per batch with ``batch_gap_s`` between
        batches (DESIGN §4). Returns ``{id: units}`` actually sent (rounded and clamped to 0..1000)."""
        items = list(targets.items())
        sent: dict[int, int] = {}
        for k in range(0, len(items), self.batch_size):
            if k:
                time.sleep(self.batch_gap_s)
            sent.update(self.move_batch(dict(items[k : k + self.batch_size]), duration_s))
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
class BusConfig:
    """How the host talks to the adapter."""

    port: str  # serial device, e.g. /dev/ttyUSB0 or the emulator's /dev/pts/N
    baud: int = C.BAUD  # bus rate, 8N1
    timeout_s: float = 0.02  # time to wait for one answer (a servo answers in ~1 ms + 0.7 ms on the wire)
    retries: int = 2  # extra attempts after a failed read
    echo: bool = False  # the adapter echoes what the host sends (single-wire adapters); discarded here
    batch_size: int = 7  # servos per batch of moves (paper)
    batch_gap_s: float = 0.010  # pause between batches in write_positions (paper)


class SerialServoBus(ServoBus):
    """:class:`ServoBus` over pyserial: 115200 8N1, echo discarded, per-read timeouts, bounded retries."""

    def __init__(self, config: BusConfig | str):
        self.config = BusConfig(config) if isinstance(config, str) else config
        self.batch_size = self.config.batch_size
        self.batch_gap_s = self.config.batch_gap_s
        self._lock = threading.RLock()
        self._serial = None
        self._decoder = StreamDecoder()
        self.stats = {"requests": 0, "retries": 0, "timeouts": 0, "checksum_errors": 0, "unexpected": 0}

    def connect(self) -> None:
        import serial  # pyserial; imported here so that the rest of the package needs no serial port

        with self._lock:
            if self._serial is not None:
                return
            try:
                cfg = self.config
                self._serial = serial.Serial(
                    cfg.port, cfg.baud, bytesize=8, parity="N", stopbits=1, timeout=cfg.timeout_s
                )
            except (serial.SerialException, OSError) as e:
                raise BusError(
                    f"cannot open servo bus {self.config.port!r}: {e}. Check the adapter is plugged in and the path "
                    "(or start `shadow-studio emulate` and use the path it prints)"
                ) from e

    def disconnect(self) -> None:
        with self._lock:
            if self._serial is not None:
                self._serial.close()
                self._serial = None

    @property
    def is_connected(self) -> bool:
        return self._serial is not None

    def _port(self):
        if self._serial is None:
            raise BusError("the servo bus is not connected: call connect() or use it as a context manager")
        return self._serial

    def _write(self, data: bytes) -> None:
        port = self._port()
        port.write(data)
        if self.config.echo:  # the adapter hears itself: the same bytes must come back first
            echo = port.read(len(data))
            if echo != data:
                raise UnexpectedReply(
                    f"adapter echo does not match what was sent ({len(echo)}/{len(data)} bytes): another device may "
                    "be driving the bus, or echo is set but the adapter does not echo (drop --echo)"
                )

    def send(self, requests: Sequence[Request]) -> None:
        data = b"".join(encode_request(i, cmd, *v) for i, cmd, v in requests)
        with self._lock:
            self._write(data)

    def request(self, servo_id: int, command: C.Command, *values: int) -> tuple[int, ...]:
        if not command.is_read:
            raise ValueError(f"{command.name} has no answer; use send()")
        packet = encode_request(servo_id, command, *values)
        error: HardwareError = ServoTimeout(servo_id)
        with self._lock:
            port = self._port()
            for attempt in range(self.config.retries + 1):
                self.stats["requests"] += 1
                if attempt:
                    self.stats["retries"] += 1
                port.reset_input_buffer()
                self._decoder.reset()
                self._write(packet)
                try:
                    return self._await(servo_id, command)
                except ChecksumError as e:
                    self.stats["checksum_errors"] += 1
                    error = e
                except UnexpectedReply as e:
                    self.stats["unexpected"] += 1
                    error = e
                except ServoTimeout as e:
                    self.stats["timeouts"] += 1
                    error = e
        raise error

    def _await(self, servo_id: int, command: C.Command) -> tuple[int, ...]:
        port = self._port()
        dec = self._decoder
        bad_before = dec.checksum_errors
        want = command.reply_len + 3
        deadline = time.perf_counter() + self.config.timeout_s
        stray = None
        while True:
            left = deadline - time.perf_counter()
            if left <= 0:
                break
            port.timeout = left
            data = port.read(max(1, min(want - len(dec.buffer), port.in_waiting or 1)))
            for pkt in dec.feed(data):
                if pkt.cmd == command.code and (pkt.servo_id == servo_id or servo_id == C.BROADCAST_ID):
                    if len(pkt.params) == command.reply_len - C.MIN_LEN:
                        return pkt.reply_values()
                stray = pkt
            if dec.checksum_errors > bad_before and not dec.buffer:
                raise ChecksumError(
                    f"servo {servo_id} answered {command.name} with a bad checksum: electrical noise, a loose "
                    "cable, or two servos sharing this ID (run `shadow-studio scan`)"
                )
        if stray is not None:
            raise UnexpectedReply(
                f"asked servo {servo_id} for {command.name} but got {C.COMMANDS.get(stray.cmd, stray.cmd)!s:.40} "
                f"from ID {stray.servo_id}: check for duplicate or misconfigured IDs (run `shadow-studio scan`)"
            )
        raise ServoTimeout(servo_id)


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
