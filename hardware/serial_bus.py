"""The servo bus over pyserial: :class:`SerialServoBus` on a half-duplex USB adapter (or the emulator's pty).

115200 8N1, the adapter's echo discarded, per-read timeouts, bounded retries. Every error of the port (pyserial's
SerialException, OSError, and the termios.error that ``reset_input_buffer``/``tcsetattr`` let through) during open,
write, read, flush or close leaves this module as a :class:`BusError` naming the port (DESIGN §5.13). pyserial is
imported on ``connect``, so nothing else needs it.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import time
from collections.abc import Sequence
from dataclasses import dataclass

from hardware import constants as C
from hardware.bus import Request, ServoBus
from hardware.errors import BusError, ChecksumError, HardwareError, ServoTimeout, UnexpectedReply
from hardware.protocol import StreamDecoder, encode_request

PORT_TIMEOUT_S = 0.02  # s a servo has to answer on a serial port: it answers in ~1 ms + 0.7 ms on the wire
# s the built-in emulator has to answer: its servos answer from a thread of this process, which shares the cores (and
# the GIL) with the studio's jobs; measured with four busy threads beside it, 0.02 s lost 43 of 100 reads of 21
# servos, 0.2 s none
EMULATOR_TIMEOUT_S = 0.2


@dataclass
class BusConfig:
    """How the host talks to the adapter."""

    port: str  # serial device, e.g. /dev/ttyUSB0 or the emulator's /dev/pts/N
    baud: int = C.BAUD  # bus rate, 8N1
    timeout_s: float | None = None  # s to wait for one answer (unset: 0.02 on a port, 0.2 on the emulator) (0, 10]
    retries: int = 2  # extra attempts after a failed read [0, 20]
    echo: bool = False  # the adapter echoes what the host sends (single-wire adapters); discarded here
    batch_size: int = 7  # servos per batch of moves (paper)
    batch_gap_s: float = 0.010  # pause between batches in write_positions (paper)
    exclusive: bool = True  # lock the port while open (POSIX flock): a second opener is told it is busy


class SerialServoBus(ServoBus):
    """:class:`ServoBus` over pyserial: 115200 8N1, echo discarded, per-read timeouts, bounded retries."""

    def __init__(self, config: BusConfig | str):
        super().__init__()
        self.config = BusConfig(config) if isinstance(config, str) else config
        self.timeout_s = PORT_TIMEOUT_S if self.config.timeout_s is None else self.config.timeout_s  # s, per answer
        self.batch_size = self.config.batch_size
        self.batch_gap_s = self.config.batch_gap_s
        self.label = f"servo bus {self.config.port!r}"
        self._serial = None
        self._decoder = StreamDecoder()
        self.stats = {"requests": 0, "retries": 0, "timeouts": 0, "checksum_errors": 0, "unexpected": 0}

    def connect(self) -> None:
        import serial  # pyserial; imported here so that the rest of the package needs no serial port

        with self._lock:
            if self._serial is not None:
                return
            cfg = self.config
            try:
                lock = cfg.exclusive or None  # None: pyserial leaves the port unlocked
                self._serial = serial.Serial(
                    cfg.port, cfg.baud, bytesize=8, parity="N", stopbits=1, timeout=self.timeout_s, exclusive=lock
                )
            except _port_errors() as e:
                raise BusError(f"cannot open servo bus {cfg.port!r}: {_open_failure(e)}") from e

    def disconnect(self) -> None:
        with self._lock:
            port, self._serial = self._serial, None
            if port is not None:
                with self._port_io("close"):
                    port.close()

    @property
    def is_connected(self) -> bool:
        return self._serial is not None

    def _port(self):
        if self._serial is None:
            raise BusError(
                f"{self.label} is not connected: it was closed or never opened; open it again (a ServoSession, "
                "connect() or a with block)"
            )
        return self._serial

    @contextlib.contextmanager
    def _port_io(self, action: str):
        """Turn any error of the port during ``action`` into a :class:`BusError` naming the port."""
        try:
            yield
        except _port_errors() as e:
            raise BusError(
                f"{self.label}: {action} failed ({e}): the adapter was unplugged or lost power, or the emulator "
                "stopped; check the cable and the port, then start again"
            ) from e

    def _write(self, data: bytes) -> None:
        port = self._port()
        port.write(data)
        if self.config.echo:  # the adapter hears itself: the same bytes must come back first
            echo = port.read(len(data))
            if echo != data:
                raise UnexpectedReply(
                    f"adapter echo does not match what was sent ({len(echo)}/{len(data)} bytes): another device may "
                    "be driving the bus, or echo is set but the adapter does not echo (turn echo off)"
                )

    def _transmit(self, requests: Sequence[Request]) -> None:
        data = b"".join(encode_request(i, cmd, *v) for i, cmd, v in requests)
        with self._lock, self._port_io("write"):
            self._write(data)

    def request(self, servo_id: int, command: C.Command, *values: int) -> tuple[int, ...]:
        if not command.is_read:
            raise ValueError(f"{command.name} has no answer; use send()")
        packet = encode_request(servo_id, command, *values)
        error: HardwareError = ServoTimeout(servo_id)
        with self._lock, self._port_io(f"asking servo {servo_id} for {command.name}"):
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
        deadline = time.perf_counter() + self.timeout_s
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
                    "cable, or two servos sharing this ID"
                )
        if stray is not None:
            raise UnexpectedReply(
                f"asked servo {servo_id} for {command.name} but got {C.COMMANDS.get(stray.cmd, stray.cmd)!s:.40} "
                f"from ID {stray.servo_id}: check for duplicate or misconfigured IDs"
            )
        raise ServoTimeout(servo_id)


def _open_failure(e: BaseException) -> str:
    """Why a port did not open, and what to do, in one line (from the errno pyserial passes on)."""
    code = getattr(e, "errno", None)
    if code in (errno.ENOENT, errno.ENODEV, errno.ENXIO):
        return "no such port. Check the adapter is plugged in and the path (or use the built-in servo emulator)"
    if code in (errno.EBUSY, errno.EAGAIN, errno.EWOULDBLOCK):
        return "the port is busy: another program or session has it open; close that first"
    if code in (errno.EACCES, errno.EPERM):
        return "permission denied: give your user access to the port (on Linux, the dialout group) and log in again"
    text = str(e).replace("\n", " ")
    return f"{text}. Check the adapter is plugged in and the path"


@functools.cache
def _port_errors() -> tuple[type[BaseException], ...]:
    """What pyserial and the OS raise when a port fails: SerialException, OSError and, on POSIX, termios.error
    (``reset_input_buffer`` and ``tcsetattr`` let it through unwrapped)."""
    import serial

    errors: list[type[BaseException]] = [serial.SerialException, OSError]
    try:
        import termios
    except ImportError:  # Windows
        pass
    else:
        errors.append(termios.error)
    return tuple(errors)
