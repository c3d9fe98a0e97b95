"""What the player plays, tick by tick: a show computed beforehand, or motion computed as it goes (live).

:class:`hardware.player.Player` runs one safe 40 Hz loop (batches, read-back, health reads, stops, the torque
policy, the log) over a :class:`TickSource`. Before the first tick it hands the source the measured starting pose;
then at every tick ``k`` it asks for that tick's pose (``None``: the source is done and playback completes) and,
once the tick's first batch has gone out on the bus, tells the source when (so a live source can time its
latency from a camera frame to the first command that carries it). Ticks may be skipped when the OS stalls the
loop: the source is asked for tick ``k`` directly and catches up itself.

:class:`ShowTicks` is a show: a ramp from the measured pose to the first frame at the ramp speed, then the show
resampled at the rate (what :meth:`hardware.player.Player.trajectory` computes).
"""

from __future__ import annotations

from typing import Protocol

import numpy as np


class TickSource(Protocol):
    """Poses for the player's ticks, calibration order, rad."""

    ramp_ticks: int  # ticks of the ramp-in from the measured pose (recorded in the playback log)
    total: int | None  # ticks in all when known beforehand (progress), None for an open-ended source

    def begin(self, start: np.ndarray) -> None:
        """Playback starts from the measured pose ``start (J,) rad``."""

    def command(self, k: int) -> np.ndarray | None:
        """The pose ``(J,) rad`` for tick ``k`` (``k`` only grows, maybe by more than one); None: done."""

    def sent(self, k: int, t_monotonic: float) -> None:
        """Tick ``k``'s first batch left for the bus at ``time.monotonic()`` = ``t_monotonic``."""


class ShowTicks:
    """A precomputed trajectory ``q (T, J) rad`` (ramp included) as a :class:`TickSource`."""

    def __init__(self, make: object):
        self._make = make  # start (J,) rad → (q (T, J) rad, ramp_ticks)
        self.q: np.ndarray | None = None
        self.ramp_ticks, self.total = 0, None

    def begin(self, start: np.ndarray) -> None:
        self.q, self.ramp_ticks = self._make(start)  # type: ignore[operator]
        self.total = len(self.q)

    def command(self, k: int) -> np.ndarray | None:
        assert self.q is not None, "begin() first"
        return None if k >= len(self.q) else self.q[k]

    def sent(self, k: int, t_monotonic: float) -> None:
        return None
