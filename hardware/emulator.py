"""Virtual LX-15D servos behind a pseudo-terminal: a byte-exact stand-in for a USB half-duplex adapter.

A background thread owns the pty master and parses the host's byte stream exactly like servos on a real bus:
every servo sees every packet, writes act on the addressed servo (or all, for broadcast ID 254), and only read
commands addressed to an existing ID are answered. Two servos with one ID answer together; on the open-drain bus
their bytes combine as a bitwise AND, which is what a host really receives. With ``echo=True`` the adapter's echo
of the host's own bytes comes back first. Faults (:class:`Faults`) can be injected at any time.

    with ServoEmulator(range(1, 22)) as emu:
        port = serial.Serial(emu.port, 115200, timeout=0.05)
"""

from __future__ import annotations

import contextlib
import logging
import os
import pty
import select
import threading
import time
import tty

import numpy as np

from hardware import constants as C
from hardware.emulator_config import EmulatorConfig, Faults
from hardware.protocol import Packet, StreamDecoder, encode_reply
from hardware.servo_model import VirtualServo

log = logging.getLogger(__name__)


class ServoEmulator:
    """21 (or any number of) virtual servos on a pty; ``port`` is the path that ``serial.Serial`` opens."""

    def __init__(
        self,
        ids=range(1, 22),
        config: EmulatorConfig | None = None,
        faults: Faults | None = None,
        positions: dict[int, int] | None = None,
        duplicate_ids: tuple[int, ...] = (),
    ):
        ids = C.check_ids(ids)  # ValueError for an ID no servo can have (254 is the broadcast address)
        duplicate_ids = tuple(C.check_ids(duplicate_ids))
        self.config = config or EmulatorConfig()
        self.faults = faults or Faults()
        start = positions or {}
        self.servos: list[VirtualServo] = [
            VirtualServo(i, start.get(i, C.CENTER_UNITS), self.config.speed_units_s) for i in ids
        ]
        for i in duplicate_ids:  # a second servo that was given an ID already in use
            twin = VirtualServo(i, start.get(i, C.CENTER_UNITS) + 137, self.config.speed_units_s)
            twin.vin_offset_mv, twin.temp_offset_c = -37, 2
            self.servos.append(twin)
        self._lock = threading.Lock()
        self._rng = np.random.default_rng(self.config.seed)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._master = self._slave = -1
        self.port = ""
        self.packets_seen = 0  # valid packets received from the host
        self.replies_sent = 0  # answers written back

    # --- lifecycle -------------------------------------------------------------------------------------------
    def start(self) -> ServoEmulator:
        """Open the pty and start the bus thread (``stop`` or the ``with`` block's end undoes both)."""
        if self._thread is not None:
            raise RuntimeError(f"the servo emulator is already running on {self.port}")
        self._master, self._slave = pty.openpty()
        try:
            tty.setraw(self._master)
            tty.setraw(self._slave)
            self.port = os.ttyname(self._slave)
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="servo-emulator", daemon=True)
            self._thread.start()
        except BaseException:
            self.stop()
            raise
        log.info("servo emulator on %s (%d servos)", self.port, len(self.servos))
        return self

    def stop(self) -> None:
        """Stop the bus thread and close the pty (safe to call twice): a host on ``port`` then sees the adapter
        vanish, as when a USB adapter is pulled."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2)
            self._thread = None
        fds, (self._master, self._slave) = (self._master, self._slave), (-1, -1)
        for fd in fds:
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)

    def __enter__(self) -> ServoEmulator:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # --- inspection and fault injection (thread-safe) ------------------------------------------------------
    def inject(self, **changes) -> None:
        """Change fault fields, e.g. ``inject(missing_ids={5})``; sets become frozensets."""
        with self._lock:
            for k, v in changes.items():
                if not hasattr(self.faults, k):
                    raise ValueError(f"unknown fault {k!r}; see hardware.emulator.Faults")
                setattr(self.faults, k, frozenset(v) if isinstance(v, (set, list, tuple, range)) else v)

    def servo(self, servo_id: int) -> VirtualServo:
        """The (first) virtual servo with this ID."""
        for s in self.servos:
            if s.servo_id == servo_id:
                return s
        raise KeyError(f"no virtual servo with ID {servo_id}")

    def positions(self) -> dict[int, float]:
        """``{id: position (servo units)}`` now, as the servos' encoders see it."""
        now = time.perf_counter()
        with self._lock:
            return {s.servo_id: s.position(now) for s in self.servos}

    def set_position(self, servo_id: int, units: float) -> None:
        """Move a servo by hand (only when its torque is off, as on a real servo)."""
        with self._lock:
            self.servo(servo_id).push(units, time.perf_counter())

    # --- the bus ---------------------------------------------------------------------------------------------
    def _run(self) -> None:
        decoder = StreamDecoder()
        while not self._stop.is_set():
            ready, _, _ = select.select([self._master], [], [], 0.05)
            if not ready:
                continue
            try:
                data = os.read(self._master, 4096)
            except OSError:  # the host side closed; wait for it to reopen
                time.sleep(0.01)
                continue
            if self.config.echo:
                os.write(self._master, data)
            for pkt in decoder.feed(data):
                self.packets_seen += 1
                reply = self._handle(pkt)
                if reply:
                    if self.config.reply_delay_s:
                        time.sleep(self.config.reply_delay_s)
                    os.write(self._master, reply)
                    self.replies_sent += 1

    def _handle(self, pkt: Packet) -> bytes:
        now = time.perf_counter()
        with self._lock:
            f = self.faults
            targets = [
                s
                for s in self.servos
                if (pkt.servo_id == C.BROADCAST_ID or s.servo_id == pkt.servo_id) and s.servo_id not in f.missing_ids
            ]
            if pkt.cmd not in C.COMMANDS:
                return b""
            command = C.COMMANDS[pkt.cmd]
            try:
                values = pkt.request_values()
            except Exception:  # a real servo ignores a malformed request
                return b""
            answers = []
            for s in targets:
                s.stuck = s.servo_id in f.stuck_ids
                s.hot_c = f.over_temp_c if s.servo_id in f.hot_ids else None
                out = s.apply(command, values, now, self.config)
                if out is None or not command.is_read:
                    continue
                if s.servo_id in f.drop_ids or self._rng.random() < f.drop_rate:
                    continue
                reply_id = (s.servo_id + 1) % (C.MAX_ID + 1) if s.servo_id in f.wrong_id_ids else s.servo_id
                raw = bytearray(encode_reply(reply_id, command, *out))
                if s.servo_id in f.corrupt_ids or self._rng.random() < f.corrupt_rate:
                    k = int(self._rng.integers(4, len(raw)))  # CMD, params or CHK: always a checksum failure
                    raw[k] ^= int(self._rng.integers(1, 256))
                answers.append(bytes(raw))
        if not answers:
            return b""
        if len(answers) == 1:
            return answers[0]
        merged = bytearray(answers[0])  # simultaneous answers on an open-drain wire: 0 wins (bitwise AND)
        for a in answers[1:]:
            merged = bytearray(x & y for x, y in zip(merged, a)) + merged[len(a) :]
        return bytes(merged)
