"""Play a show to the built-in emulator: 21 virtual LX-15D servos on a pseudo-terminal (POSIX only).

The same path as ``shadow-studio play SHOW --dry-run``, for scripts and notebooks::

    from hardware.dry_run import play_on_emulator
    result = play_on_emulator(show)          # PlaybackResult: reason, sent vs measured, timing

Real pyserial talks to the emulator exactly as it would to a USB adapter, so everything but the servos is real.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from hardware.calibration import Calibration, load_calibration
from hardware.errors import BusError
from hardware.playback_log import PlaybackResult
from hardware.player import Player, PlayerConfig, SampleHook
from hardware.serial_bus import BusConfig, SerialServoBus
from studio.motion.show import Show
from studio.sim.hand import Hand, load_hand


def play_on_emulator(
    show: Show,
    calibration: Calibration | None = None,
    config: PlayerConfig | None = None,
    hand: Hand | None = None,
    progress: Callable[[int, int], None] | None = None,
    cancel: threading.Event | None = None,
    on_sample: SampleHook | None = None,
) -> PlaybackResult:
    """Start the emulator with the calibration's servo IDs, play ``show`` through real pyserial, stop it again.

    ``calibration`` defaults to the shipped one; ``on_sample`` is the player's per-tick hook (review's commanded vs
    measured series). Never raises for a stop condition (the result says why); raises ``BusError`` where the
    emulator cannot run (no pseudo-terminals on this system).
    """
    try:
        from hardware.emulator import ServoEmulator  # POSIX only (pty): imported when used
    except ImportError as e:
        raise BusError(f"the servo emulator needs POSIX pseudo-terminals, which this system lacks ({e})") from None
    cal = calibration or load_calibration(None, hand or load_hand())
    with ServoEmulator(cal.ids) as emu, SerialServoBus(BusConfig(emu.port)) as bus:
        return Player(bus, cal, config or PlayerConfig(), on_sample=on_sample).play(
            show.times, show.positions, show.joint_names, cancel=cancel, progress=progress
        )
