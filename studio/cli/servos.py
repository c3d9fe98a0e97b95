"""Verbs ``emulate``, ``scan``, ``calibrate`` and ``play``: the terminal face of the hardware layer (``jog``:
:mod:`studio.cli.jog`, on this module's :func:`session_for`).

They open the servos through :class:`hardware.session.ServoSession` and fail safe (DESIGN §5.13): however a verb
ends, the session stops every servo and leaves torque held (``play --release-on-stop``: released); a lost port
(``BusError``) ends the verb with one line and exit code 2 (through ``main``); ``calibrate`` carries on after a
servo misses a read, checks ``--out`` before it touches the bus and keeps what was calibrated in
``<out>.partial.yaml`` when it ends early. ``play`` writes its log however it ends (``--log``, default
``<studio home>/logs/play-<time>.npz``). Ctrl-C, SIGTERM and SIGHUP end ``play`` and ``calibrate`` alike
(``studio.cli.signals``): stop sent, torque as configured, log written, one line, exit code 128 + the signal
(Ctrl-C 130, SIGTERM 143). ``play`` refuses before it opens the port while the e-stop is latched (any process:
``hardware.estop``; ``shadow-studio estop --reset`` clears it) and when the show was planned for another hand
(unless ``--force``). Servo IDs are 0..253 wherever they are typed. The emulator (POSIX only: pty, termios) is
imported only by the verbs that use it.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from functools import partial
from pathlib import Path

import numpy as np

from hardware.bus import scan
from hardware.calibration import (
    Calibration,
    check_writable,
    default_calibration,
    load_calibration,
    save_calibration,
)
from hardware.constants import parse_ids
from hardware.emulator_config import EmulatorConfig, Faults
from hardware.errors import BusError, EStopLatched, ProtocolError, ServoTimeout
from hardware.estop import check_not_latched
from hardware.playback_log import PlaybackResult, StopReason, save_playback_log
from hardware.player import Player, PlayerConfig
from hardware.serial_bus import BusConfig
from hardware.session import ServoSession, load_emulator
from hardware.show_checks import beyond_soft_limits, check_mount, check_show_hand, soft_limit_text
from hardware.wizard import CalibrationWizard
from studio.cli.flags import add_config_flags, config_from_args, ranged
from studio.cli.play_camera import add_camera_flags, prepare_camera
from studio.cli.progress import add_quiet_flag
from studio.cli.runs import advice
from studio.cli.servo_logs import log_path, save_log
from studio.cli.signals import exit_code, stop_on_signals
from studio.sim.hand import load_hand
from studio.sim.roll import mount_text


def _ids(text: str) -> list[int]:
    """``"1-21"`` or ``"3,5,9-11"`` → list of IDs in 0..253: an argparse type (a bad list is one usage line)."""
    try:
        return parse_ids(text)
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


def bus_args(p: argparse.ArgumentParser, port_required: bool = True) -> None:
    p.add_argument("--port", required=port_required, help="serial device (or the path `emulate` prints)")
    add_config_flags(
        p, BusConfig, ("echo", "timeout_s", "retries"), base=BusConfig(""), aliases={"timeout_s": "timeout"}
    )


def session_for(
    args, calibration: Calibration | None = None, emulator: bool = False, release: bool = False
) -> ServoSession:
    """The :class:`ServoSession` a verb opens: ``--port`` (or the emulator) with the link flags (``--echo``,
    ``--timeout``, ``--retries``); on close torque is held, or released when ``release``."""
    config = config_from_args(args, BusConfig, base=BusConfig(args.port or ""))
    port = None if emulator else args.port
    return ServoSession(port, calibration=calibration, config=config, release_on_close=release)


def cmd_emulate(args) -> int:
    em = load_emulator()
    ids = {k: frozenset(getattr(args, k)) for k in ("missing", "stuck", "hot")}
    faults = config_from_args(args, Faults, **{f"{k}_ids": v for k, v in ids.items()})
    dups = tuple(args.duplicate)
    emulator = em.ServoEmulator(args.ids, config_from_args(args, EmulatorConfig), faults, duplicate_ids=dups)
    with stop_on_signals("emulate"), emulator as emu:  # Ctrl-C, SIGTERM, SIGHUP: the pty is closed, exit 0
        print(emu.port, flush=True)
        print(f"{len(emu.servos)} virtual servos; Ctrl-C to stop", file=sys.stderr, flush=True)
        try:
            while True:
                time.sleep(0.5)
        except KeyboardInterrupt as e:
            print(f"stopped ({e or 'Ctrl-C'}) after {emu.packets_seen} packets", file=sys.stderr)
    return 0


def cmd_scan(args) -> int:
    expected = load_calibration(args.calibration, load_hand()).ids if args.calibration else []
    with session_for(args) as session:
        report = scan(session.bus, args.ids, expected)
    print(f"present: {report.present or 'none'}")
    if report.duplicates:
        print(f"DUPLICATE IDs (two servos answer at once): {report.duplicates}: give one of each a new ID")
    if report.missing:
        print(f"missing from the calibration: {report.missing}")
    return 1 if report.duplicates or report.missing else 0


def _save_progress(wiz: CalibrationWizard, out: Path) -> str:
    """Save what was calibrated so far to ``<out>.partial.yaml``; returns the sentence that says so."""
    cal = wiz.progress()
    if cal is None:
        return "nothing saved"
    path = out.with_suffix(".partial.yaml")
    save_calibration(cal, path)
    return f"progress ({', '.join(wiz.calibrated)}) saved to {path}: resume with --start {path} and skip those joints"


def cmd_calibrate(args) -> int:
    check_writable(args.out)  # before the bus: a session is not lost to a typo in --out
    hand = load_hand()
    start = load_calibration(args.start, hand) if args.start else default_calibration(hand)
    with stop_on_signals("calibrate"), session_for(args, start) as session:
        wiz = CalibrationWizard(session.bus, hand, start)
        print("commands: + - 'step N' free hold set skip   (empty line = set)")
        print(wiz.prompt())
        try:
            for line in sys.stdin:
                try:
                    print(wiz.execute(line))
                except (ValueError, ServoTimeout, ProtocolError, EStopLatched) as e:  # a missed read: type it again
                    print(f"? {e}{advice(e)}")
                if wiz.finished:
                    break
        except BusError as e:  # the port is gone: keep what was done, say so in the one error line
            raise BusError(f"{e}; {_save_progress(wiz, args.out)}") from e
        except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM, SIGHUP: main says "interrupted", exit 128 + signal
            print(f"stopped by {e or 'Ctrl-C'}; {_save_progress(wiz, args.out)}", file=sys.stderr)
            raise
        if not wiz.finished:
            print(f"input ended before every joint was calibrated; {_save_progress(wiz, args.out)}", file=sys.stderr)
            return 1
        for note in wiz.notes:
            print(f"note: {note}")
        result = wiz.result()
        if args.roll is not None:  # how the hand is mounted on this rig: only shows for that roll play on it
            result = replace(result, roll=math.radians(args.roll))
        save_calibration(result, args.out)
    print(f"saved {args.out}")
    return 0


def cmd_play(args) -> int:
    from studio.jobs.bars import TqdmBars
    from studio.motion.show import load_show

    hand = load_hand()
    cal = load_calibration(args.calibration, hand)
    show = load_show(args.show, hand)
    check_show_hand(show.hand_hash, hand, args.show, force=args.force)
    check_mount(show.roll, cal, args.calibration)
    cfg = PlayerConfig(hold_torque_on_stop=not args.release_on_stop)
    if not args.dry_run and not args.port:
        raise ValueError("give --port PATH (or --dry-run to play to the emulator)")
    check_not_latched(args.port or "the emulator")  # before the port is opened: nothing to undo
    camera = prepare_camera(args, show)  # --camera: its flags and the show's targets, before the port too
    log_to = log_path(args.log, "play", ".npz")
    with stop_on_signals("play") as caught, session_for(args, cal, args.dry_run, args.release_on_stop) as session:
        if session.emulator is not None:
            print(f"dry run: playing to the emulator on {session.emulator.port}")
        print(f"playing {show.title!r}: {show.duration:.2f} s, {len(show.times)} samples; Ctrl-C stops safely")
        print(f"mount: {mount_text(show.roll)}")
        if note := soft_limit_text(beyond_soft_limits(show.positions, show.joint_names, cal)):
            print(f"note: {note}")
        player = Player(session.bus, cal, cfg)
        try:
            with TqdmBars(disable=args.quiet) as bars:
                if camera is None:
                    result = player.play(show.times, show.positions, show.joint_names, progress=bars)
                else:  # the camera refuses before the servos move when it sees no backdrop
                    result = (captured := camera.play(session, player, show, bars)).playback
        finally:  # the log is written however playback ended (even by a bug, which then surfaces)
            if player.last_result is not None:
                write = partial(save_playback_log, player.last_result)
                save_log(write, log_to, args.log, "command vs measured")
        session.close()  # the servos stopped before the verb reports (a later signal is ignored till it returns)
        _report(result)
        if camera is not None:
            camera.report(captured, log_to)
    if result.reason == StopReason.INTERRUPTED:  # Ctrl-C, SIGTERM, SIGHUP: the shell's code for that signal
        return exit_code(caught[0] if caught else None)
    return 0 if result.ok else 1


def _report(result: PlaybackResult) -> None:
    """The outcome: one line (stdout when completed, stderr when stopped), then the timing on stdout."""
    line = f"{result.reason.value}: {result.message}; torque {result.torque}"
    print(line if result.ok else f"shadow-studio play: stopped: {line}", file=sys.stdout if result.ok else sys.stderr)
    late = np.abs(result.lateness_s) * 1000
    at_limit, at_step = int(result.clipped_limit.any(1).sum()), int(result.clipped_step.any(1).sum())
    if len(late):
        print(
            f"{len(result.sent)} ticks (ramp {result.ramp_ticks}), {result.commands} commands, tick jitter p50 "
            f"{np.percentile(late, 50):.2f} ms p99 {np.percentile(late, 99):.2f} ms, ticks clipped: {at_limit} at "
            f"the soft limits, {at_step} at the step limit; max tracking error {result.max_tracking_error_rad:.3f} rad"
        )


def register(sub) -> None:
    p = sub.add_parser("emulate", help="run 21 virtual LX-15D servos on a pseudo-terminal until Ctrl-C")
    p.add_argument("--ids", type=_ids, default="1-21", help="servo IDs present, 0..253 (default 1-21)")
    add_config_flags(p, EmulatorConfig, ("echo",))
    add_config_flags(p, Faults, ("drop_rate", "corrupt_rate"))
    p.add_argument("--missing", type=_ids, default="", help="IDs that do not answer, e.g. 5,7")
    p.add_argument("--stuck", type=_ids, default="", help="IDs with a locked rotor")
    p.add_argument("--hot", type=_ids, default="", help="IDs that report over-temperature")
    p.add_argument("--duplicate", type=_ids, default="", help="IDs that a second servo also uses")
    p.set_defaults(func=cmd_emulate)

    p = sub.add_parser("scan", help="find the servos on a bus and flag duplicate IDs")
    bus_args(p)
    p.add_argument("--ids", type=_ids, default="0-253", help="IDs to try (default 0-253)")
    p.add_argument("--calibration", type=Path, help="also report the calibration's servos that do not answer")
    p.set_defaults(func=cmd_scan, retries=0)

    p = sub.add_parser("calibrate", help="set each joint's zero and limits by jogging (reads commands on stdin)")
    bus_args(p)
    p.add_argument("--out", type=Path, required=True, help="calibration YAML to write")
    p.add_argument("--start", type=Path, help="calibration to start from (IDs, values for 'skip'); default IDs 1-21")
    p.add_argument("--roll", type=ranged(float, "[-360, 360]"), default=None, metavar="DEG",
                   help="record the rig's mount roll (degrees, counter-clockwise as the audience sees it): only "
                        "shows made for that roll will play with this calibration (default: the --start file's, "
                        "else not recorded)")  # fmt: skip
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("play", help="play a show file on the servos at 40 Hz with safety stops")
    p.add_argument("show", type=Path, help="show file (.json)")
    bus_args(p, port_required=False)
    p.add_argument("--calibration", type=Path, help="calibration YAML (default: assets/calibration.yaml)")
    p.add_argument("--dry-run", action="store_true", help="play to a built-in emulator instead of --port")
    p.add_argument("--release-on-stop", action="store_true", help="release torque when stopped early")
    p.add_argument("--log", type=Path, help="save command vs measured positions to this .npz (default: "
                   "<studio home>/logs/play-<time>.npz)")  # fmt: skip
    p.add_argument("--force", action="store_true", help="play a show planned for another hand model")
    add_camera_flags(p)
    add_quiet_flag(p)
    p.set_defaults(func=cmd_play)
