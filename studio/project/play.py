"""The play job: a show played through ``hardware.player`` on the built-in emulator or a given bus.

``hardware`` is imported inside the worker function only (DESIGN §3: of the studio, only ``project.jobs`` reaches
the servos). Progress is ``("play", tick, ticks)``. Cancel stops the player within a tick (its own cancel event,
a safe stop with torque as configured) and the job ends ``cancelled``. Any other stop (e-stop, fault, lost bus,
tracking error) fails the job with :class:`PlaybackStopped` saying why, so nothing is applied.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from studio.errors import StudioError
from studio.jobs.events import Reporter
from studio.jobs.job import Job

if TYPE_CHECKING:
    from hardware.calibration import Calibration
    from hardware.player import PlayerConfig
    from studio.motion.show import Show


class PlaybackStopped(StudioError):
    """A show stopped before its end for a reason other than a cancel; the message is the player's reason."""


def play_job(
    show: Show,
    *,
    calibration: Calibration | None = None,
    config: PlayerConfig | None = None,
    bus: Any = None,
    on_sample: Callable | None = None,
    apply: Callable[[Any], None] | None = None,
    title: str = "",
) -> Job:
    """Play ``show`` → ``PlaybackResult``. ``bus`` None plays on the emulator (real pyserial over a
    pseudo-terminal, ``hardware.dry_run.play_show``); a connected ``ServoBus`` plays on it (thread worker only: a
    bus does not pickle). ``calibration`` defaults to the shipped one; ``on_sample(t, commanded,
    measured)`` is the player's per-tick hook, called in the worker (thread worker: any callable)."""
    run = functools.partial(_play, show=show, calibration=calibration, config=config, bus=bus, on_sample=on_sample)
    return Job("play", run, apply, title or (show.title or "show"))


def _play(report: Reporter, cancel, *, show, calibration, config, bus, on_sample):
    from hardware.dry_run import play_show
    from hardware.player import StopReason

    result = play_show(show, calibration, config, progress=report, cancel=cancel, on_sample=on_sample, bus=bus)
    if result.reason not in (StopReason.COMPLETED, StopReason.CANCELLED):
        raise PlaybackStopped(f"playback stopped ({result.reason.value}): {result.message}")
    return result
