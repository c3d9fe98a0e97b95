"""What a playback did: why it stopped (:class:`StopReason`), the rows recorded tick by tick (:class:`Recording`),
the :class:`PlaybackResult` made from them, and its log file (``.npz``, written through ``studio.atomic``).

The player records into a :class:`Recording` as it goes and turns it into a result however playback ends, so a
show that crashed half-way still leaves a log of the ticks it played.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path

import numpy as np

from hardware.safety import Clipped
from studio.atomic import write_with


class StopReason(str, Enum):
    """Why playback ended."""

    COMPLETED = "completed"
    INTERRUPTED = "interrupted"  # Ctrl-C or a stop signal (SIGTERM, SIGHUP); the message says which
    CANCELLED = "cancelled"
    ESTOP = "e-stop"
    FAULT = "servo fault"
    OVER_TEMPERATURE = "over-temperature"
    LOST_COMMUNICATION = "lost communication"
    TRACKING_ERROR = "tracking error"
    CALLBACK_ERROR = "callback error"  # the on_sample or progress hook raised
    ERROR = "internal error"  # an unexpected exception (a bug); the player re-raises it after the safe stop


@dataclass
class PlaybackResult:
    """What happened; arrays cover the ticks actually played (ramp included)."""

    reason: StopReason  # why playback ended
    message: str  # one sentence for the user
    torque: str  # "held", "released" or "unknown" (the bus failed while stopping)
    ramp_ticks: int  # ticks spent ramping before the show's first frame
    t: np.ndarray  # (T,) s planned times of the ticks played, from the start of the ramp
    skipped_ticks: int  # ticks dropped because the OS stalled the player for more than a tick
    requested: np.ndarray  # (T, J) rad asked for (ramp + show), calibration joint order
    sent: np.ndarray  # (T, J) rad actually commanded after clipping
    clipped_limit: np.ndarray  # (T, J) bool: request beyond a soft limit
    clipped_step: np.ndarray  # (T, J) bool: request beyond the max step per tick
    lateness_s: np.ndarray  # (T,) s actual start of each tick minus its deadline
    measured_t: np.ndarray  # (M,) s time of each position read-back
    measured_joint: np.ndarray  # (M,) joint index read
    measured_rad: np.ndarray  # (M,) rad measured
    max_tracking_error_rad: float  # worst distance of a read-back from the recent commands
    commands: int  # move packets sent
    joint_names: list[str] = field(default_factory=list)  # column order

    @property
    def ok(self) -> bool:
        return self.reason == StopReason.COMPLETED


@dataclass
class Recording:
    """Rows collected while playing (turned into a :class:`PlaybackResult` by :meth:`result`)."""

    joints: int  # J, number of joints (columns of every (T, J) row block)
    ramp_ticks: int = 0  # ticks of the ramp to the first frame
    ticks: list = field(default_factory=list)  # tick index of each commanded row
    requested: list = field(default_factory=list)  # (J,) rad asked for, per tick
    sent: list = field(default_factory=list)  # (J,) rad commanded after clipping, per tick
    at_limit: list = field(default_factory=list)  # (J,) bool, per tick
    at_step: list = field(default_factory=list)  # (J,) bool, per tick
    late: list = field(default_factory=list)  # s lateness of each tick's first batch
    meas_t: list = field(default_factory=list)  # s time of each read-back since tick 0
    meas_j: list = field(default_factory=list)  # joint index of each read-back
    meas_q: list = field(default_factory=list)  # rad of each read-back
    worst: float = 0.0  # rad worst tracking error seen
    commands: int = 0  # move packets sent
    misses: np.ndarray | None = None  # (J,) consecutive failed reads per joint
    measured: np.ndarray | None = None  # (J,) rad latest read-back per joint
    history: np.ndarray | None = None  # (K, J) rad the last K commands sent
    t0: float = 0.0  # perf_counter time of tick 0

    def __post_init__(self) -> None:
        if self.misses is None:
            self.misses = np.zeros(self.joints, dtype=int)

    def record_command(self, k: int, requested: np.ndarray, c: Clipped) -> None:
        """Tick ``k`` asked for ``requested (J,) rad`` and sent ``c.sent``."""
        self.ticks.append(k)
        self.history = np.roll(self.history, -1, 0)
        self.history[-1] = c.sent
        self.sent.append(c.sent)
        self.requested.append(requested)
        self.at_limit.append(c.at_limit)
        self.at_step.append(c.at_step)

    def record_reading(self, t: float, j: int, q: float) -> None:
        """Joint ``j`` read ``q`` rad at ``t`` s after tick 0."""
        self.measured[j] = q
        self.meas_t.append(t)
        self.meas_j.append(j)
        self.meas_q.append(q)

    def result(
        self, reason: StopReason, message: str, torque: str, rate_hz: float, joint_names: list[str]
    ) -> PlaybackResult:
        """The rows so far as a :class:`PlaybackResult`."""
        J = self.joints

        def rows(x: list, dtype=float) -> np.ndarray:
            return np.array(x, dtype=dtype).reshape(len(x), J)

        return PlaybackResult(
            reason=reason,
            message=message,
            torque=torque,
            ramp_ticks=self.ramp_ticks,
            t=np.array(self.ticks, dtype=float) / rate_hz,
            skipped_ticks=(self.ticks[-1] + 1 - len(self.ticks)) if self.ticks else 0,
            requested=rows(self.requested),
            sent=rows(self.sent),
            clipped_limit=rows(self.at_limit, bool),
            clipped_step=rows(self.at_step, bool),
            lateness_s=np.array(self.late, dtype=float),
            measured_t=np.array(self.meas_t, dtype=float),
            measured_joint=np.array(self.meas_j, dtype=int),
            measured_rad=np.array(self.meas_q, dtype=float),
            max_tracking_error_rad=self.worst,
            commands=self.commands,
            joint_names=list(joint_names),
        )


def save_playback_log(result: PlaybackResult, path: str | Path) -> Path:
    """Write command vs measured positions (and why playback ended) to ``path`` as ``.npz``, atomically.

    Keys: ``t (T,)``, ``requested``/``sent (T, J)`` rad, ``measured_t``/``measured_joint``/``measured_rad (M,)``,
    ``joint_names (J,)``, ``reason`` (the :class:`StopReason` name), ``message``, ``torque``. Returns the path."""

    def write(f) -> None:
        np.savez(
            f, t=result.t, requested=result.requested, sent=result.sent, measured_t=result.measured_t,
            measured_joint=result.measured_joint, measured_rad=result.measured_rad,
            joint_names=np.array(result.joint_names, dtype=str), reason=result.reason.name, message=result.message,
            torque=result.torque,
        )  # fmt: skip

    return write_with(path, write)
