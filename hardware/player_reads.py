"""What the player reads back from the servos between its batches (mixed into :class:`hardware.player.Player`): one
position read after each batch (a tracking error stops the show), one health read a tick (faults, temperature or
voltage, round robin), each read tolerated ``max_missed_reads − 1`` times in a row, and the exception that ends the
playback loop with the reason it stopped (:class:`StopPlayback`)."""

from __future__ import annotations

import logging
import time

import numpy as np

from hardware.errors import OverTemperature, ProtocolError, ServoFault, ServoTimeout
from hardware.playback_log import Recording, StopReason
from hardware.safety import check_faults, check_temperature, check_voltage, tracking_error

log = logging.getLogger("hardware.player")  # the player's log: one place to read a show's stops


class StopPlayback(Exception):
    """Ends the playback loop: ``reason`` and its ``message`` (the player then stops safely and records them)."""

    def __init__(self, reason: StopReason, message: str):
        super().__init__(message)
        self.reason, self.message = reason, message


class PlayerReads:
    """Reads of ``Player`` (it provides ``bus``, ``cal`` and ``safety``)."""

    def _read_back(self, j: int, rec: Recording) -> None:
        """Read joint ``j``'s position, log it, and stop on a tracking error."""
        val = self._read(j, rec.misses, self.bus.read_position)
        if val is None:
            return
        q = self.cal.to_rad(np.full(len(self.cal.ids), float(val)))[j]
        rec.record_reading(time.perf_counter() - rec.t0, j, q)
        err = tracking_error(q, rec.history[:, j])
        rec.worst = max(rec.worst, err)
        if err > self.safety.max_tracking_error_rad:
            raise StopPlayback(
                StopReason.TRACKING_ERROR,
                f"{self.cal.joint_names[j]} (servo {self.cal.ids[j]}) is {err:.2f} rad from its command "
                f"(limit {self.safety.max_tracking_error_rad} rad): blocked, overloaded or stuck",
            )

    def _read(self, j: int, misses: np.ndarray, fn):
        """One read of joint ``j``'s servo; None on a (tolerated) miss, ``StopPlayback`` after too many in a row."""
        sid = self.cal.ids[j]
        try:
            val = fn(sid)
        except (ServoTimeout, ProtocolError) as e:
            misses[j] += 1
            log.debug("read of servo %d failed (%d in a row): %s", sid, misses[j], e)  # tolerated; a stop says more
            if misses[j] >= self.safety.max_missed_reads:
                raise StopPlayback(
                    StopReason.LOST_COMMUNICATION,
                    f"{self.cal.joint_names[j]} (servo {sid}) failed {misses[j]} reads in a row: {e}",
                ) from e
            return None
        misses[j] = 0
        return val

    def _health(self, cursor: int, misses: np.ndarray) -> None:
        j, kind = (cursor // 3) % len(self.cal.ids), cursor % 3
        sid, name = self.cal.ids[j], self.cal.joint_names[j]
        reader = (self.bus.read_faults, self.bus.read_temperature, self.bus.read_voltage)[kind]
        val = self._read(j, misses, reader)
        if val is None:
            return
        try:
            if kind == 0:
                check_faults(sid, name, val)
            elif kind == 1:
                check_temperature(sid, name, val, self.safety)
            else:
                check_voltage(sid, name, val, self.safety)
        except OverTemperature as e:
            raise StopPlayback(StopReason.OVER_TEMPERATURE, str(e)) from e
        except ServoFault as e:
            raise StopPlayback(StopReason.FAULT, str(e)) from e
