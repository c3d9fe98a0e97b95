"""How a live session runs (:func:`studio.project.live.run_live`): a plain dataclass with no torch import, so
``shadow-studio live`` builds its flags without loading the engine."""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["LiveConfig"]


@dataclass(frozen=True)
class LiveConfig:
    """How a live session runs."""

    roll_deg: float | None = None  # the mount's roll, degrees (unset: the calibration's; 0 if it has none) [-180, 180]
    speed_scale: float = 1.0  # share of the joints' velocity, acceleration and jerk limits the motion uses (0, 1]
    ramp_speed_rad_s: float = 0.5  # joint speed of the ramp-in from the measured pose to the first target (0, 5]
    max_seconds: float = 0.0  # end the session after this long, s; 0: until stopped or a video file ends [0, 86400]
    stall_s: float = 1.0  # no new camera frame for this long: the hand holds and says so, s (0, 60]
    backdrop: str = "auto"  # "auto": the backdrop's homography when its markers are in the first frame; "none"
    hold_torque_on_stop: bool = True  # after a stop the servos hold their pose (True) or go limp (False)

    def __post_init__(self) -> None:
        roll_ok = self.roll_deg is None or -180 <= self.roll_deg <= 180
        if not roll_ok or not 0 < self.speed_scale <= 1 or not 0 < self.ramp_speed_rad_s <= 5:
            raise ValueError("live: roll_deg in [-180, 180], speed_scale in (0, 1], ramp_speed_rad_s in (0, 5] rad/s")
        if not 0 <= self.max_seconds <= 86400 or not 0 < self.stall_s <= 60:
            raise ValueError("live: max_seconds in [0, 86400] s (0: no limit), stall_s in (0, 60] s")
        if self.backdrop not in ("auto", "none"):
            raise ValueError(f"live: backdrop must be 'auto' or 'none', not {self.backdrop!r}")

    def mount_roll(self, calibrated: float | None) -> float:
        """The session's mount roll, rad: ``roll_deg``, or when unset the ``calibrated`` roll (rad; None: 0)."""
        if self.roll_deg is None:
            return 0.0 if calibrated is None else float(calibrated)
        return math.radians(self.roll_deg)
