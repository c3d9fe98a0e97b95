"""The live hand's motion, tick by tick: Ruckig online from the commanded state to the newest target pose.

:class:`LiveTicks` is the :class:`~hardware.tick_source.TickSource` the player streams in the live mode. The
planner thread hands it targets (:meth:`LiveTicks.aim`: a pose and the camera frame it answers); every 40 Hz tick
the player asks for the next pose and :class:`~studio.motion.online.OnlineMotion` steps toward the newest target
within the joints' velocity, acceleration and jerk limits, recomputed from the current state every tick (so a
target that changes mid-move bends the motion without a jump). It starts at rest at the hand's measured pose and
ramps in at ``ramp_speed_rad_s`` until it first reaches a target; with no target yet, or none new (the camera
stalled, the silhouette vanished), the hand holds where it is.

Once the first batch of a tick that carries a new target has gone out on the bus, the tick's send time minus the
frame's arrival time is that target's latency (:attr:`LiveTicks.latencies`). :meth:`LiveTicks.finish` ends the
stream once the hand has come to rest on its last target (a video file that ended); :meth:`LiveTicks.stop` at once.

Poses are in the calibration's joint order here (the player's); the planner's poses are in the hand's order and
:meth:`aim` reorders them.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace

import numpy as np

from studio.motion.limits import JointLimits
from studio.motion.online import OnlineConfig, OnlineMotion


@dataclass
class Aim:
    """A target handed to the motion."""

    theta: np.ndarray  # (J,) rad, calibration order
    frame_t: float  # time.monotonic() at which the camera frame it answers arrived
    frame_index: int  # that frame's index
    sent_t: float | None = None  # time.monotonic() of the first command that carried it (None: not sent yet)
    tick: int | None = None  # that command's tick


class LiveTicks:
    """Online motion for the player (module doc). ``limits``: in the calibration's joint order."""

    def __init__(
        self,
        limits: JointLimits,
        order: list[int],
        rate_hz: float = 40.0,
        speed_scale: float = 1.0,
        ramp_speed_rad_s: float = 0.5,
    ):
        self.limits, self.order = limits, list(order)  # order[j]: the hand's index of calibration joint j
        self.cfg = OnlineConfig(rate_hz=rate_hz, speed_scale=speed_scale)
        self.ramp = replace(limits, velocity=np.minimum(limits.velocity * speed_scale, ramp_speed_rad_s) / speed_scale)
        self.ramp_ticks, self.total = 0, None
        self.motion: OnlineMotion | None = None
        self._lock = threading.Lock()
        self._pending: Aim | None = None  # newest target not yet taken by a tick
        self._current: Aim | None = None  # target the motion is heading for
        self._ramping = True
        self._done = threading.Event()  # finish(): end at rest on the last target
        self._stop = threading.Event()  # stop(): end now
        self.aims: list[Aim] = []  # every target taken by a tick, in order
        self.started = threading.Event()  # begin() ran: the measured start pose is known
        self.start: np.ndarray | None = None  # (J,) rad, measured start pose (calibration order)
        self.commanded: np.ndarray | None = None  # (J,) rad, the pose of the last tick (calibration order)

    # --- the planner's side ----------------------------------------------------------------------------------
    def aim(self, theta_hand: np.ndarray, frame_t: float, frame_index: int) -> None:
        """Head for ``theta_hand (21,) rad`` (the hand's order), answering the frame that arrived at ``frame_t``."""
        theta = np.asarray(theta_hand, dtype=np.float64)[self.order]
        with self._lock:
            self._pending = Aim(theta, frame_t, frame_index)

    def commanded_hand(self) -> np.ndarray | None:
        """The last tick's pose in the hand's order (None before the first tick)."""
        with self._lock:
            if self.commanded is None:
                return None
            out = np.empty(len(self.order))
            out[self.order] = self.commanded
            return out

    def finish(self) -> None:
        """End the stream once the hand rests on its last target (no more targets will come)."""
        self._done.set()

    def stop(self) -> None:
        """End the stream at the next tick (the player then completes; the hand holds where it was commanded)."""
        self._stop.set()

    @property
    def latencies(self) -> np.ndarray:
        """(U,) s, from each sent target's camera frame to its first command."""
        with self._lock:
            return np.array([a.sent_t - a.frame_t for a in self.aims if a.sent_t is not None], dtype=float)

    # --- the player's side -----------------------------------------------------------------------------------
    def begin(self, start: np.ndarray) -> None:
        start = np.clip(np.asarray(start, dtype=np.float64), self.limits.lower, self.limits.upper)
        self.motion = OnlineMotion(self.ramp, start, self.cfg)
        self.start, self.commanded, self._k = start.copy(), start.copy(), -1
        self.started.set()

    def command(self, k: int) -> np.ndarray | None:
        assert self.motion is not None, "begin() first"
        if self._stop.is_set():
            return None
        with self._lock:
            aim, self._pending = self._pending, None
        if aim is not None:
            aim.tick = k
            self.motion.set_target(aim.theta)
            with self._lock:
                self._current = aim
                self.aims.append(aim)
        for _ in range(max(1, k - self._k)):  # a stalled loop catches up with the clock
            q = self.motion.step()
        self._k = k
        if self._ramping and self._current is not None and self.motion.at_target:
            self._ramping = False  # ramped in: the joints' own limits from now on
            self.ramp_ticks = k
            self.motion.limits = self.limits
        if self._done.is_set() and self._pending is None and self.motion.at_target:
            return None
        with self._lock:
            self.commanded = q
        return q

    def sent(self, k: int, t_monotonic: float) -> None:
        with self._lock:
            cur = self._current
            if cur is not None and cur.tick == k and cur.sent_t is None:
                cur.sent_t = t_monotonic
