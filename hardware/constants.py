"""LX-15D / LX-16A bus-servo constants: the packet layout, the command table and the servo's units.

Every number here comes from the LewanSoul/Hiwonder "Bus Servo Communication Protocol" (the same table that the
public LX-16A drivers use). Packet: ``55 55 ID LEN CMD params CHK``, ``LEN = len(params) + 3``,
``CHK = ~(ID + LEN + CMD + Σparams) & 0xFF``, 16-bit values little-endian.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass

HEADER = b"\x55\x55"  # two start bytes of every packet
BROADCAST_ID = 254  # a write to this ID reaches every servo; no servo answers a broadcast write
MAX_ID = 253  # servo IDs are 0..253
MIN_LEN = 3  # LEN of a packet without parameters
MAX_LEN = 7  # the longest packet in the table carries 4 parameter bytes

BAUD = 115200  # the bus rate, 8N1 (10 bits on the wire per byte)
BYTE_TIME_S = 10 / BAUD  # ≈ 86.8 µs per byte on the wire

POS_UNITS = 1000  # positions 0..1000 …
POS_RANGE_DEG = 240.0  # … span 0..240 degrees
UNITS_PER_RAD = POS_UNITS / math.radians(POS_RANGE_DEG)  # ≈ 238.7 servo units per radian
CENTER_UNITS = 500  # mid travel (120 deg)
MAX_MOVE_TIME_MS = 30000  # longest move time a servo accepts
OFFSET_MIN, OFFSET_MAX = -125, 125  # angle offset range, servo units (±30 deg)
SERVO_SPEED_UNITS_S = math.radians(60) * UNITS_PER_RAD / 0.16  # LX-15D no-load speed: 0.16 s per 60 deg
DEFAULT_TEMP_LIMIT_C = 85  # factory over-temperature limit
DEFAULT_VIN_LIMITS_MV = (4500, 12000)  # factory voltage window

# Bits of the LED error / fault byte (SERVO_LED_ERROR_READ).
FAULT_OVER_TEMPERATURE = 0x01
FAULT_OVER_VOLTAGE = 0x02
FAULT_LOCKED_ROTOR = 0x04
FAULT_NAMES = {FAULT_OVER_TEMPERATURE: "over-temperature", FAULT_OVER_VOLTAGE: "over-voltage",
               FAULT_LOCKED_ROTOR: "locked rotor"}  # fmt: skip


@dataclass(frozen=True)
class Command:
    """One entry of the command table."""

    name: str  # protocol name without the SERVO_ prefix
    code: int  # CMD byte
    params: str  # struct format of what the host sends ("" = no parameters), little-endian
    reply: str | None  # struct format of the servo's answer; None for commands a servo never answers

    @property
    def is_read(self) -> bool:
        return self.reply is not None

    @property
    def request_len(self) -> int:
        """LEN byte of the host's packet."""
        return struct.calcsize(self.params) + MIN_LEN

    @property
    def reply_len(self) -> int:
        """LEN byte of the servo's answer."""
        return struct.calcsize(self.reply or "<") + MIN_LEN


def _c(name: str, code: int, params: str, reply: str | None = None) -> Command:
    return Command(name, code, params, reply)


MOVE_TIME_WRITE = _c("MOVE_TIME_WRITE", 1, "<HH")  # position 0..1000, time 0..30000 ms; moves now
MOVE_TIME_READ = _c("MOVE_TIME_READ", 2, "<", "<HH")  # last move: position, time
MOVE_TIME_WAIT_WRITE = _c("MOVE_TIME_WAIT_WRITE", 7, "<HH")  # like MOVE_TIME_WRITE, waits for MOVE_START
MOVE_TIME_WAIT_READ = _c("MOVE_TIME_WAIT_READ", 8, "<", "<HH")  # the waiting move: position, time
MOVE_START = _c("MOVE_START", 11, "<")  # start the waiting move (usually broadcast)
MOVE_STOP = _c("MOVE_STOP", 12, "<")  # stop where it is
ID_WRITE = _c("ID_WRITE", 13, "<B")  # new ID 0..253 (kept after power-off)
ID_READ = _c("ID_READ", 14, "<", "<B")  # the servo's ID (answers a broadcast when alone on the bus)
ANGLE_OFFSET_ADJUST = _c("ANGLE_OFFSET_ADJUST", 17, "<b")  # offset -125..125 units, takes effect now, not saved
ANGLE_OFFSET_WRITE = _c("ANGLE_OFFSET_WRITE", 18, "<")  # save the adjusted offset
ANGLE_OFFSET_READ = _c("ANGLE_OFFSET_READ", 19, "<", "<b")  # offset, signed byte
ANGLE_LIMIT_WRITE = _c("ANGLE_LIMIT_WRITE", 20, "<HH")  # min, max position 0..1000
ANGLE_LIMIT_READ = _c("ANGLE_LIMIT_READ", 21, "<", "<HH")
VIN_LIMIT_WRITE = _c("VIN_LIMIT_WRITE", 22, "<HH")  # min, max input voltage, mV (4500..12000)
VIN_LIMIT_READ = _c("VIN_LIMIT_READ", 23, "<", "<HH")
TEMP_MAX_LIMIT_WRITE = _c("TEMP_MAX_LIMIT_WRITE", 24, "<B")  # over-temperature limit 50..100 °C
TEMP_MAX_LIMIT_READ = _c("TEMP_MAX_LIMIT_READ", 25, "<", "<B")
TEMP_READ = _c("TEMP_READ", 26, "<", "<B")  # °C
VIN_READ = _c("VIN_READ", 27, "<", "<H")  # mV
POS_READ = _c("POS_READ", 28, "<", "<h")  # position, signed (a servo can sit slightly below 0)
OR_MOTOR_MODE_WRITE = _c("OR_MOTOR_MODE_WRITE", 29, "<BBh")  # mode (0 servo, 1 motor), 0, speed -1000..1000
OR_MOTOR_MODE_READ = _c("OR_MOTOR_MODE_READ", 30, "<", "<BBh")
LOAD_OR_UNLOAD_WRITE = _c("LOAD_OR_UNLOAD_WRITE", 31, "<B")  # 1 torque on, 0 torque off
LOAD_OR_UNLOAD_READ = _c("LOAD_OR_UNLOAD_READ", 32, "<", "<B")
LED_CTRL_WRITE = _c("LED_CTRL_WRITE", 33, "<B")  # 0 LED on, 1 LED off
LED_CTRL_READ = _c("LED_CTRL_READ", 34, "<", "<B")
LED_ERROR_WRITE = _c("LED_ERROR_WRITE", 35, "<B")  # which faults flash the LED (FAULT_* bits)
LED_ERROR_READ = _c("LED_ERROR_READ", 36, "<", "<B")  # current faults (FAULT_* bits)

COMMANDS: dict[int, Command] = {
    c.code: c
    for c in (
        MOVE_TIME_WRITE, MOVE_TIME_READ, MOVE_TIME_WAIT_WRITE, MOVE_TIME_WAIT_READ, MOVE_START, MOVE_STOP,
        ID_WRITE, ID_READ, ANGLE_OFFSET_ADJUST, ANGLE_OFFSET_WRITE, ANGLE_OFFSET_READ, ANGLE_LIMIT_WRITE,
        ANGLE_LIMIT_READ, VIN_LIMIT_WRITE, VIN_LIMIT_READ, TEMP_MAX_LIMIT_WRITE, TEMP_MAX_LIMIT_READ, TEMP_READ,
        VIN_READ, POS_READ, OR_MOTOR_MODE_WRITE, OR_MOTOR_MODE_READ, LOAD_OR_UNLOAD_WRITE, LOAD_OR_UNLOAD_READ,
        LED_CTRL_WRITE, LED_CTRL_READ, LED_ERROR_WRITE, LED_ERROR_READ,
    )
}  # fmt: skip


# Commands that make a servo move: refused while the e-stop is latched (torque on, LOAD_OR_UNLOAD_WRITE 1, too).
# ANGLE_OFFSET_ADJUST shifts a loaded horn at once; motor mode spins it.
MOTION_CODES = frozenset(
    c.code for c in (MOVE_TIME_WRITE, MOVE_TIME_WAIT_WRITE, MOVE_START, OR_MOTOR_MODE_WRITE, ANGLE_OFFSET_ADJUST)
)


def describe_faults(bits: int) -> str:
    """``"over-temperature, locked rotor"`` for a fault byte; ``"none"`` for 0."""
    names = [n for b, n in FAULT_NAMES.items() if bits & b]
    return ", ".join(names) if names else "none"


def check_ids(ids: Iterable[int], what: str = "servo ID") -> list[int]:
    """``ids`` as a list, or ``ValueError`` naming the first outside 0..MAX_ID (254 is the broadcast address, which
    no servo has)."""
    out = [int(i) for i in ids]
    bad = [i for i in out if not 0 <= i <= MAX_ID]
    if bad:
        raise ValueError(f"{what} {bad[0]} is outside 0..{MAX_ID} ({BROADCAST_ID} is the broadcast address)")
    return out


def parse_ids(text: str) -> list[int]:
    """``"1-21"`` or ``"3,5,9-11"`` (``""``: none) → the list of servo IDs, each in 0..MAX_ID; ``ValueError`` saying
    what is wrong otherwise."""
    out: list[int] = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        a, dash, b = part.partition("-")
        if not a.strip().isdigit() or (dash and not b.strip().isdigit()):
            raise ValueError(f"{part!r} is not an ID or a range of IDs: write e.g. 5 or 1-21 or 3,5,9-11")
        lo, hi = int(a), int(b) if dash else int(a)
        if hi < lo:
            raise ValueError(f"{part!r} runs backwards: write the lower ID first, e.g. {hi}-{lo}")
        if dash and hi > MAX_ID:
            raise ValueError(f"{part!r} goes past {MAX_ID}: servo IDs are 0..{MAX_ID} ({BROADCAST_ID} is the broadcast "
                             "address)")  # fmt: skip
        out.extend(check_ids(range(lo, hi + 1)))
    return out
