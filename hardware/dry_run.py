"""Play a show: on a connected bus, or (a dry run) on the built-in emulator, 21 virtual LX-15D servos on a
pseudo-terminal (POSIX only).

The same path as ``shadow-studio play SHOW --dry-run``, for scripts and notebooks::

    from hardware.dry_run import play_on_emulator
    result = play_on_emulator(show)          # PlaybackResult: reason, sent vs measured, timing

Real pyserial talks to the emulator exactly as it would to a USB adapter, so everything but the servos is real.
``play_on_emulator`` is :func:`play_show` under the name scripts know: without ``bus`` it plays on the emulator.
"""

from __future__ import annotations

import threading

from hardware.bus import ServoBus
from hardware.calibration import Calibration, load_calibration
from hardware.playback_log import PlaybackResult
from hardware.player import Player, PlayerConfig, SampleHook
from hardware.session import ServoSession
from hardware.show_checks import check_mount, check_show_hand
from studio.errors import ProgressFn
from studio.motion.show import Show
from studio.sim.hand import Hand, load_hand


def play_show(
    show: Show,
    calibration: Calibration | None = None,
    config: PlayerConfig | None = None,
    hand: Hand | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    on_sample: SampleHook | None = None,
    *,
    bus: ServoBus | None = None,
    force: bool = False,
) -> PlaybackResult:
    """Play ``show`` through a :class:`~hardware.player.Player` on ``bus`` (connected; left open), or, when
    ``bus`` is None, on the emulator started for it with the calibration's servo IDs (a
    :class:`~hardware.session.ServoSession`, closed with torque as ``config`` leaves it).

    ``calibration`` defaults to the shipped one; ``progress`` gets ``Progress("play", tick, ticks)``;
    ``on_sample`` is the player's per-tick hook (review's commanded vs measured series). Never raises for a stop
    condition (the result says why); raises ``BusError`` where the emulator cannot run (no pseudo-terminals on this
    system), :class:`~hardware.errors.MountMismatch` before anything moves when ``calibration`` records the rig
    at another mount roll than the show's, and :class:`~hardware.errors.ShowForAnotherHand` when the show was
    planned for another hand model (unless ``force``).
    """
    hand = hand or load_hand()
    cal = calibration or load_calibration(None, hand)
    check_show_hand(show.hand_hash, hand, force=force)  # another hand's limits and speeds: refused unless forced
    check_mount(show.roll, cal)  # a rig calibrated at another roll: refused before the servos are touched
    cfg = config or PlayerConfig()
    if bus is None:
        with ServoSession(calibration=cal, release_on_close=not cfg.hold_torque_on_stop) as session:
            return play_show(show, cal, cfg, hand, progress, cancel, on_sample, bus=session.bus, force=force)
    player = Player(bus, cal, cfg, on_sample=on_sample)
    return player.play(show.times, show.positions, show.joint_names, cancel=cancel, progress=progress)


play_on_emulator = play_show  # without ``bus``: start the emulator, play ``show`` through real pyserial, stop it
