"""Timed show playback at 40 Hz with safety: the steady clock, batching, read-back and safe stops.

Timing (115200 baud, DESIGN §4). One move packet is 10 bytes ≈ 0.87 ms on the wire, so a batch of 7 servos
takes ≈ 6.1 ms and all 21 servos ≈ 18.2 ms. The paper's "7 per batch, 10 ms between batches" taken literally
(3 × 6.1 ms + 2 × 10 ms idle = 38 ms, or 10 ms start-to-start = 26.1 ms) does not fit one 25 ms tick, so the
player keeps 7 servos per batch and spreads the batches evenly over the tick (start-to-start 25/3 ≈ 8.3 ms,
≈ 2.2 ms idle after each). Each idle slot carries one position read (6 + 8 bytes ≈ 1.2 ms) and the last slot of a
tick one health read (faults, temperature or voltage), so positions come back at 40·3/21 ≈ 5.7 Hz per servo and
health at ≈ 0.6 Hz per servo. Every move carries a move time of one tick, so each servo interpolates linearly to
its next sample. Tick *k* starts at the absolute deadline ``t0 + k / rate``: a late tick never delays the next.

Stops: Ctrl-C, :meth:`Player.estop`, the cancel event, a fault bit, over-temperature, out-of-range voltage,
``max_missed_reads`` failed reads of one servo, a tracking error, a lost port (``BusError``), a raising hook, or
a bug. Whatever ends the loop (DESIGN §5.13), the player sends MOVE_STOP (best effort: a failing stop makes the
torque "unknown"), holds or releases torque as configured and records the result in :attr:`Player.last_result`,
which says why; only a bug is then re-raised. The e-stop is the bus's latch (:meth:`ServoBus.estop`), shared by
every process through its file (:mod:`hardware.estop`): while it is latched :meth:`Player.play` sends a stop and
returns ESTOP at once, and one pressed anywhere during a show stops it before the next batch; only a reset
(``bus.reset_estop()``, ``shadow-studio estop --reset``) clears it. A stop signal that the command line turns into
``KeyboardInterrupt`` (SIGTERM, SIGHUP: ``studio.cli.signals``) ends playback as Ctrl-C does, its message naming it.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hardware.bus import ServoBus
from hardware.calibration import Calibration
from hardware.errors import (
    BusError,
    EStopLatched,
    HardwareError,
    ProtocolError,
    ServoTimeout,
)
from hardware.playback_log import PlaybackResult, Recording, StopReason
from hardware.player_reads import PlayerReads, StopPlayback
from hardware.safety import SafetyConfig, clip_command
from hardware.tick_source import ShowTicks, TickSource
from studio.errors import Progress, ProgressFn

__all__ = ["PlaybackResult", "Player", "PlayerConfig", "SampleHook", "StopReason"]

log = logging.getLogger(__name__)

SampleHook = Callable[[float, np.ndarray, np.ndarray], None]  # (t s, commanded (J,) rad, measured (J,) rad)


@dataclass
class PlayerConfig:
    """How a show is played."""

    rate_hz: float = 40.0  # controller rate (paper)
    batch_size: int = 7  # servos per batch (paper)
    batch_spacing_s: float | None = None  # start-to-start between batches; None: spread evenly over the tick
    reads_per_batch: int = 1  # position reads in the idle time after each batch
    health_reads: bool = True  # one fault/temperature/voltage read per tick, round robin
    ramp_speed_rad_s: float = 0.5  # speed of the ramp from the measured pose to the first frame
    hold_torque_on_stop: bool = True  # after a stop: True keeps torque (hand holds its pose), False releases it


class Player(PlayerReads):
    """Plays ``(times, positions, joint_names)`` on a connected bus through a calibration."""

    def __init__(
        self,
        bus: ServoBus,
        calibration: Calibration,
        config: PlayerConfig | None = None,
        safety: SafetyConfig | None = None,
        on_sample: SampleHook | None = None,
    ):
        self.bus, self.cal = bus, calibration
        self.cfg = config or PlayerConfig()
        self.safety = safety or SafetyConfig()
        self.on_sample = on_sample
        self.last_result: PlaybackResult | None = None  # set however the last play() ended, even by raising
        period = 1.0 / self.cfg.rate_hz
        n_batches = -(-len(calibration.joints) // self.cfg.batch_size)
        self.spacing = self.cfg.batch_spacing_s if self.cfg.batch_spacing_s is not None else period / n_batches
        if self.spacing * (n_batches - 1) >= period:
            raise ValueError(
                f"{n_batches} batches {self.spacing * 1000:.1f} ms apart do not fit a {period * 1000:.1f} ms tick: "
                "lower batch_spacing_s or rate_hz"
            )

    def estop(self) -> bool:
        """Latch the bus's e-stop and halt every servo now (thread-safe; call from a UI or signal handler).

        Playback ends with ESTOP; nothing moves again until ``bus.reset_estop()``. Returns whether the halt reached
        the bus."""
        return self.bus.estop(by="the player")

    def _columns(self, times: np.ndarray, positions: np.ndarray, joint_names: list[str]):
        """Check a show; returns ``(times (N,) s, q (N, J) rad in calibration order)`` or raises ValueError."""
        times = np.asarray(times, dtype=float)
        positions = np.asarray(positions, dtype=float)
        if positions.ndim != 2 or positions.shape != (len(times), len(joint_names)) or len(times) < 1:
            raise ValueError(f"positions must be (N, {len(joint_names)}) for {len(times)} times; got {positions.shape}")
        if len(times) > 1 and not np.all(np.diff(times) > 0):
            raise ValueError("show times must be strictly increasing")
        if sorted(joint_names) != sorted(self.cal.joint_names):
            raise ValueError(f"show joints {joint_names} do not match the calibration's {self.cal.joint_names}")
        cols = [joint_names.index(n) for n in self.cal.joint_names]
        return times, positions[:, cols]

    def trajectory(self, times: np.ndarray, positions: np.ndarray, joint_names: list[str], start: np.ndarray):
        """Ticks to play: a ramp from ``start (J,) rad`` to the first frame, then the show resampled at the rate.

        Returns ``(q (T, J) rad in calibration order, ramp_ticks)``."""
        times, q = self._columns(times, positions, joint_names)
        dt = 1.0 / self.cfg.rate_hz
        tk = np.arange(0.0, times[-1] - times[0] + 1e-9, dt) + times[0]
        show = np.stack([np.interp(tk, times, q[:, j]) for j in range(q.shape[1])], 1)
        first = np.clip(show[0], self.cal.lower, self.cal.upper)
        here = np.clip(start, self.cal.lower, self.cal.upper)
        n_ramp = int(np.ceil(np.max(np.abs(first - here)) / (self.cfg.ramp_speed_rad_s * dt)))
        ramp = here + (first - here) * (np.arange(1, n_ramp + 1) / max(n_ramp, 1))[:, None]
        return np.concatenate([ramp, show]), n_ramp

    def play(
        self,
        times: np.ndarray,
        positions: np.ndarray,
        joint_names: list[str],
        cancel: threading.Event | None = None,
        progress: ProgressFn | None = None,
    ) -> PlaybackResult:
        """Play ``positions (N, J) rad`` at ``times (N,) s`` (columns named by ``joint_names``); ``progress`` gets
        ``Progress("play", tick, ticks)`` after every tick (the ramp to the first pose included).

        Never raises for a stop condition, a lost bus, a raising hook or Ctrl-C: the result says why it stopped and
        what torque state it left. A malformed show raises ValueError before anything is sent; an unexpected
        exception (a bug) is re-raised after the safe stop, with what was played in :attr:`last_result`."""
        self._columns(times, positions, joint_names)  # a bad show fails here, before the bus is touched
        show = ShowTicks(lambda start: self.trajectory(times, positions, joint_names, start))
        return self.stream(show, cancel, progress)

    def stream(
        self, source: TickSource, cancel: threading.Event | None = None, progress: ProgressFn | None = None
    ) -> PlaybackResult:
        """Play what ``source`` gives tick by tick (:mod:`hardware.tick_source`: a show, or live motion) with the
        same safety as :meth:`play`; ``progress`` gets ``Progress("play", tick, total)`` (total 0 when open-ended).
        Never raises for a stop condition; a raising source is a bug (re-raised after the safe stop)."""
        rec = Recording(len(self.cal.ids))
        self.last_result = None
        if self.bus.estop_latched:
            return self._finish(StopReason.ESTOP, self.bus.latch_message(), rec)
        try:
            reason, message = self._run(source, rec, cancel, progress)
        except StopPlayback as s:
            reason, message = s.reason, s.message
        except EStopLatched:
            reason, message = StopReason.ESTOP, "e-stop pressed"
        except BusError as e:
            reason, message = StopReason.LOST_COMMUNICATION, str(e)
        except HardwareError as e:
            reason, message = StopReason.LOST_COMMUNICATION, f"the bus failed: {e}"
        except KeyboardInterrupt as e:  # Ctrl-C, or a stop signal raised as one (str names it: "SIGTERM")
            reason, message = StopReason.INTERRUPTED, f"stopped by {e or 'Ctrl-C'}"
        except BaseException as e:  # a bug: stop safely and keep the log, then let it surface
            self._finish(StopReason.ERROR, f"playback crashed ({type(e).__name__}: {e})", rec)
            raise
        return self._finish(reason, message, rec)

    def _run(self, source: TickSource, rec: Recording, cancel, progress) -> tuple[StopReason, str]:
        """The playback loop; returns ``(COMPLETED, message)`` or raises what stopped it."""
        ids, J, dt = self.cal.ids, len(self.cal.ids), 1.0 / self.cfg.rate_hz
        try:
            start = self.cal.to_rad(np.array([self.bus.read_position(i) for i in ids], dtype=float))
        except (ServoTimeout, ProtocolError) as e:
            raise StopPlayback(StopReason.LOST_COMMUNICATION, f"cannot read the starting pose: {e}") from e
        source.begin(start)
        rec.ramp_ticks = source.ramp_ticks
        rec.measured = start.copy()
        rec.history = np.repeat(start[None], self.safety.tracking_lag_ticks, 0)
        batches = [list(range(k, min(k + self.cfg.batch_size, J))) for k in range(0, J, self.cfg.batch_size)]
        reads = health = 0
        prev = start
        max_step = self.safety.max_speed_rad_s * dt
        rec.t0 = time.perf_counter() + 0.002
        k = -1
        while True:
            # next tick; if the OS stalled us past a whole tick, skip to the current one (keeps sync with the
            # clock; the step limit then spreads the catch-up over several ticks)
            behind = int((time.perf_counter() - rec.t0) / dt)
            k = max(k + 1, behind if source.total is None else min(behind, source.total - 1))
            want = source.command(k)
            if want is None:
                break
            deadline = rec.t0 + k * dt
            c = clip_command(want, prev, self.cal.lower, self.cal.upper, max_step)
            units = self.cal.to_units(c.sent)
            for b, batch in enumerate(batches):
                self._check_stop(cancel)
                _sleep_until(deadline + b * self.spacing)
                if b == 0:
                    rec.late.append(time.perf_counter() - deadline)
                self.bus.move_batch({ids[j]: units[j] for j in batch}, dt)  # EStopLatched once latched
                rec.commands += len(batch)
                if b == 0:
                    source.sent(k, time.monotonic())
                    prev = c.sent
                    rec.record_command(k, want, c)
                for _ in range(self.cfg.reads_per_batch):
                    self._read_back(reads % J, rec)
                    reads += 1
            if self.cfg.health_reads:
                self._health(health, rec.misses)
                health += 1
            if self.on_sample is not None:
                self._hook("on_sample", self.on_sample, k * dt, c.sent.copy(), rec.measured.copy())
            if progress is not None:
                self._hook("progress", progress, Progress("play", k + 1, source.total or 0))
        played = k  # the tick that found the source done
        skipped = played - len(rec.ticks)
        return StopReason.COMPLETED, f"played {played} ticks ({played * dt:.2f} s, {skipped} skipped)"

    @staticmethod
    def _hook(name: str, fn: Callable, *args) -> None:
        """Call a user hook; an exception from it stops playback (CALLBACK_ERROR), Ctrl-C stays Ctrl-C."""
        try:
            fn(*args)
        except Exception as e:
            log.error("the %s callback raised; stopping playback", name, exc_info=True)
            raise StopPlayback(StopReason.CALLBACK_ERROR, f"the {name} callback raised {type(e).__name__}: {e}") from e

    def _check_stop(self, cancel: threading.Event | None) -> None:
        if self.bus.estop_latched:
            raise StopPlayback(StopReason.ESTOP, "e-stop pressed")
        if cancel is not None and cancel.is_set():
            raise StopPlayback(StopReason.CANCELLED, "cancelled")

    def _finish(self, reason: StopReason, message: str, rec: Recording) -> PlaybackResult:
        """Halt (unless completed), apply the torque policy, and record the result; never raises."""
        torque = "held"
        if reason != StopReason.COMPLETED:
            try:
                self.bus.stop()
                if not self.cfg.hold_torque_on_stop:
                    self.bus.set_torque(False)
                    torque = "released"
            except Exception as e:  # best effort: the result (and the log) must still come back
                torque = "unknown"
                log.debug("stopping the servos failed: %s", e)
                message += "; the stop could not be sent either: cut the servos' power"
            log.debug("playback stopped: %s: %s (torque %s)", reason.value, message, torque)
        self.last_result = rec.result(reason, message, torque, self.cfg.rate_hz, self.cal.joint_names)
        return self.last_result


def _sleep_until(t: float) -> None:
    """Sleep to the absolute perf_counter time ``t`` (the last 0.3 ms in short naps, for a tight deadline)."""
    while True:
        left = t - time.perf_counter()
        if left <= 0:
            return
        time.sleep(left - 0.0003 if left > 0.001 else left / 2)
