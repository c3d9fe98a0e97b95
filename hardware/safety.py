"""The safety layer shared by the player and the jog tool: soft limits, step limits, tracking and health checks.

Pure functions on arrays (no IO): the caller reads the servos and sends the commands; these decide what may be
sent and whether a reading means "stop".
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hardware import constants as C
from hardware.errors import OverTemperature, ServoFault


def urdf_max_speed() -> float:
    """The fastest joint velocity limit in the shipped hand's URDF, rad/s: the one place the servo speed is stated
    (LX-15D: 0.2 s per 60°); the player's step per tick is this speed times the tick."""
    from studio.sim.hand import load_hand

    return float(max(j.velocity for j in load_hand().joints))


@dataclass
class SafetyConfig:
    """Limits that stop or shape motion (defaults: LX-15D datasheet and the hand's URDF)."""

    max_speed_rad_s: float = field(default_factory=urdf_max_speed)  # fastest commanded joint speed (URDF velocity)
    max_temp_c: int = 70  # stop above this servo temperature, °C (the servo itself cuts out at 85 °C)
    min_voltage_v: float = 6.0  # stop below this supply voltage (LX-15D: 6.0-8.4 V)
    max_voltage_v: float = 8.6  # stop above this supply voltage
    max_tracking_error_rad: float = 0.35  # stop when a joint is this far from every recent command
    tracking_lag_ticks: int = 6  # a servo may lag this many ticks of commands behind
    max_missed_reads: int = 3  # consecutive failed reads (after the bus's retries) of one servo = lost link


@dataclass(frozen=True)
class Clipped:
    """The result of clipping one command."""

    sent: np.ndarray  # (J,) rad actually commanded
    at_limit: np.ndarray  # (J,) bool: the request lay beyond a soft limit
    at_step: np.ndarray  # (J,) bool: the request was further than one step from the previous command

    @property
    def any(self) -> bool:
        return bool(self.at_limit.any() or self.at_step.any())


def clip_command(
    target: np.ndarray, previous: np.ndarray | None, lower: np.ndarray, upper: np.ndarray, max_step: float
) -> Clipped:
    """Clip ``target (J,) rad`` into ``[lower, upper]`` and to within ``max_step`` rad of ``previous (J,)``."""
    target = np.asarray(target, dtype=float)
    inside = np.clip(target, lower, upper)
    at_limit = inside != target
    if previous is None:
        return Clipped(inside, at_limit, np.zeros_like(at_limit))
    prev = np.asarray(previous, dtype=float)
    step = np.clip(inside - prev, -max_step, max_step)
    sent = np.clip(prev + step, lower, upper)
    return Clipped(sent, at_limit, np.abs(inside - prev) > max_step + 1e-12)


def move_time(delta_rad: np.ndarray, max_speed_rad_s: float, at_least_s: float = 0.0) -> float:
    """Shortest duration (s) that keeps every joint of ``delta_rad`` within ``max_speed_rad_s``."""
    return max(at_least_s, float(np.max(np.abs(delta_rad), initial=0.0)) / max_speed_rad_s)


def tracking_error(measured: float, recent: np.ndarray) -> float:
    """Distance (rad) from a measured angle to the span of the recent commands ``recent (K,)`` of that joint."""
    lo, hi = float(np.min(recent)), float(np.max(recent))
    return max(0.0, lo - measured, measured - hi)


def check_faults(servo_id: int, joint: str, bits: int) -> None:
    """Raise ``OverTemperature``/``ServoFault`` when a servo's fault byte is not 0."""
    if bits & C.FAULT_OVER_TEMPERATURE:
        raise OverTemperature(servo_id, f"servo {servo_id} ({joint}) reports over-temperature: let it cool down")
    if bits:
        raise ServoFault(
            servo_id,
            f"servo {servo_id} ({joint}) reports {C.describe_faults(bits)}: free the joint, check the linkage "
            "and power-cycle the servo",
        )


def check_temperature(servo_id: int, joint: str, temp_c: float, cfg: SafetyConfig) -> None:
    if temp_c > cfg.max_temp_c:
        raise OverTemperature(
            servo_id, f"servo {servo_id} ({joint}) is at {temp_c:.0f} °C, above {cfg.max_temp_c} °C: let it cool down"
        )


def check_voltage(servo_id: int, joint: str, vin_v: float, cfg: SafetyConfig) -> None:
    if not cfg.min_voltage_v <= vin_v <= cfg.max_voltage_v:
        raise ServoFault(
            servo_id,
            f"servo {servo_id} ({joint}) sees {vin_v:.2f} V, outside {cfg.min_voltage_v}-{cfg.max_voltage_v} V: "
            "check the power supply",
        )
