"""LX-15D packets: encode, decode and a streaming decoder that resynchronises on ``55 55`` in a noisy stream.

Pure byte manipulation (no IO): the bus and the emulator both build on it, so host and virtual servos speak
exactly the same format.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

from hardware.constants import BROADCAST_ID, COMMANDS, HEADER, MAX_ID, MAX_LEN, MIN_LEN, Command
from hardware.errors import ChecksumError, ProtocolError


def checksum(servo_id: int, length: int, cmd: int, params: bytes) -> int:
    """``~(ID + LEN + CMD + Σparams) & 0xFF``."""
    return ~(servo_id + length + cmd + sum(params)) & 0xFF


@dataclass(frozen=True)
class Packet:
    """One decoded packet (a host request or a servo's answer)."""

    servo_id: int  # 0..253, or 254 for broadcast
    cmd: int  # command code (see ``hardware.constants``)
    params: bytes = b""  # raw parameter bytes

    @property
    def command(self) -> Command:
        if self.cmd not in COMMANDS:
            raise ProtocolError(f"unknown command {self.cmd} in packet for servo {self.servo_id}")
        return COMMANDS[self.cmd]

    def to_bytes(self) -> bytes:
        return encode(self.servo_id, self.cmd, self.params)

    def request_values(self) -> tuple[int, ...]:
        """The host's parameters, unpacked with the command table (raises ``ProtocolError`` on a bad size)."""
        return _unpack(self.command.params, self.params, self)

    def reply_values(self) -> tuple[int, ...]:
        """A servo's answer, unpacked with the command table."""
        fmt = self.command.reply
        if fmt is None:
            raise ProtocolError(f"{self.command.name} has no reply")
        return _unpack(fmt, self.params, self)


def _unpack(fmt: str, params: bytes, pkt: Packet) -> tuple[int, ...]:
    if struct.calcsize(fmt) != len(params):
        raise ProtocolError(
            f"{pkt.command.name} for servo {pkt.servo_id}: expected {struct.calcsize(fmt)} parameter bytes, "
            f"got {len(params)}"
        )
    return struct.unpack(fmt, params)


def encode(servo_id: int, cmd: int, params: bytes = b"") -> bytes:
    """Raw packet bytes ``55 55 ID LEN CMD params CHK``."""
    if not 0 <= servo_id <= BROADCAST_ID:
        raise ValueError(f"servo ID must be 0..{MAX_ID} (or {BROADCAST_ID} for broadcast), got {servo_id}")
    length = len(params) + MIN_LEN
    if length > MAX_LEN + 3:  # generous: never hit by the table
        raise ValueError(f"too many parameters ({len(params)}) for one packet")
    return HEADER + bytes((servo_id, length, cmd)) + bytes(params) + bytes((checksum(servo_id, length, cmd, params),))


def encode_request(servo_id: int, command: Command, *values: int) -> bytes:
    """A host packet for ``command`` with its parameters packed by the command table."""
    return encode(servo_id, command.code, struct.pack(command.params, *values))


def encode_reply(servo_id: int, command: Command, *values: int) -> bytes:
    """A servo's answer to the read ``command`` (what the emulator sends)."""
    if command.reply is None:
        raise ValueError(f"{command.name} is not a read command")
    return encode(servo_id, command.code, struct.pack(command.reply, *values))


def decode(frame: bytes) -> Packet:
    """Decode exactly one complete packet; raises ``ProtocolError``/``ChecksumError`` saying what is wrong."""
    frame = bytes(frame)
    if len(frame) < MIN_LEN + 3 or frame[:2] != HEADER:
        raise ProtocolError(f"not an LX-15D packet (needs 55 55 header and 6+ bytes): {frame.hex(' ')}")
    servo_id, length, cmd = frame[2], frame[3], frame[4]
    if len(frame) != length + 3:
        raise ProtocolError(f"packet length byte says {length + 3} bytes, got {len(frame)}: {frame.hex(' ')}")
    params = frame[5:-1]
    want = checksum(servo_id, length, cmd, params)
    if frame[-1] != want:
        raise ChecksumError(f"bad checksum from servo {servo_id}: got {frame[-1]:#04x}, expected {want:#04x}")
    return Packet(servo_id, cmd, params)


@dataclass
class StreamDecoder:
    """Turns a byte stream into packets, skipping garbage and resynchronising on ``55 55``.

    A frame with a bad checksum or impossible length is dropped one byte at a time, so a real packet hidden
    behind garbage (even garbage that starts with ``55 55``) is still found.
    """

    max_len: int = 10  # largest LEN byte accepted (the table tops out at 7)
    buffer: bytearray = field(default_factory=bytearray)  # bytes not yet decoded
    checksum_errors: int = 0  # frames dropped for a bad checksum since creation
    skipped_bytes: int = 0  # garbage bytes dropped while resynchronising

    def feed(self, data: bytes) -> list[Packet]:
        """Add bytes; return every complete valid packet now decodable, in order."""
        self.buffer += data
        out: list[Packet] = []
        buf = self.buffer
        while True:
            start = buf.find(HEADER)
            if start < 0:
                keep = 1 if buf[-1:] == HEADER[:1] else 0
                self.skipped_bytes += len(buf) - keep
                del buf[: len(buf) - keep]
                break
            if start:
                self.skipped_bytes += start
                del buf[:start]
            if len(buf) < 5:
                break
            length = buf[3]
            if not MIN_LEN <= length <= self.max_len or buf[2] > BROADCAST_ID:
                self._drop_one()
                continue
            if len(buf) < length + 3:
                break
            frame = bytes(buf[: length + 3])
            try:
                pkt = decode(frame)
            except ChecksumError:
                self.checksum_errors += 1
                self._drop_one()
                continue
            del buf[: length + 3]
            out.append(pkt)
        return out

    def _drop_one(self) -> None:
        self.skipped_bytes += 1
        del self.buffer[:1]

    def reset(self) -> None:
        """Forget buffered bytes (after a timeout, so stale halves cannot join the next answer)."""
        self.buffer.clear()
