"""What the servo emulator injects and how its virtual bus behaves: plain dataclasses, no pseudo-terminal.

Kept apart from ``hardware.emulator`` (POSIX only: pty, termios) so that the CLI can build the ``emulate`` verb's
flags from these fields on any system.
"""

from __future__ import annotations

from dataclasses import dataclass

from hardware import constants as C


@dataclass
class Faults:
    """Faults to inject; change them through :meth:`ServoEmulator.inject` while the emulator runs."""

    drop_rate: float = 0.0  # probability that any answer is silently dropped [0, 1]
    corrupt_rate: float = 0.0  # probability that one byte of an answer (CMD..CHK) is flipped [0, 1]
    drop_ids: frozenset[int] = frozenset()  # servos whose answers are always dropped (they still move)
    corrupt_ids: frozenset[int] = frozenset()  # servos whose answers always carry a flipped byte
    missing_ids: frozenset[int] = frozenset()  # servos unplugged: they neither move nor answer
    stuck_ids: frozenset[int] = frozenset()  # locked rotors: they do not move and report FAULT_LOCKED_ROTOR
    hot_ids: frozenset[int] = frozenset()  # servos that run at over_temp_c and report FAULT_OVER_TEMPERATURE
    wrong_id_ids: frozenset[int] = frozenset()  # servos that answer with the wrong ID in the packet
    over_temp_c: int = 92  # temperature a hot servo reports, °C


@dataclass
class EmulatorConfig:
    """How the virtual bus behaves."""

    echo: bool = False  # the adapter echoes the host's bytes (single-wire adapters do)
    reply_delay_s: float = 0.0  # extra latency before each answer (a real servo answers within ~1 ms)
    vin_mv: int = 7400  # supply voltage every servo reports, mV
    temp_c: int = 38  # temperature of a healthy servo, °C
    speed_units_s: float = C.SERVO_SPEED_UNITS_S  # top speed of a servo, units/s
    seed: int = 0  # seed of the fault-injection random generator
