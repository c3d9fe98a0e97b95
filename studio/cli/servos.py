"""Verbs ``emulate``, ``scan``, ``calibrate``, ``play`` and ``jog``: the terminal face of the hardware layer."""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
from pathlib import Path

import numpy as np

from hardware.bus import scan
from hardware.calibration import default_calibration, load_calibration, save_calibration
from hardware.jog import HELP, Jog
from hardware.player import Player, PlayerConfig
from hardware.serial_bus import BusConfig, SerialServoBus
from hardware.wizard import CalibrationWizard
from studio.sim.hand import load_hand


def _ids(text: str) -> list[int]:
    """``"1-21"`` or ``"3,5,9-11"`` → list of IDs."""
    out: list[int] = []
    for part in filter(None, text.split(",")):
        a, _, b = part.partition("-")
        out.extend(range(int(a), int(b or a) + 1))
    return out


def _bus_args(p: argparse.ArgumentParser, port_required: bool = True) -> None:
    p.add_argument("--port", required=port_required, help="serial device (or the path `emulate` prints)")
    p.add_argument("--echo", action="store_true", help="the adapter echoes what it sends (single-wire adapters)")
    p.add_argument("--timeout", type=float, default=0.02, help="seconds to wait for each answer (default 0.02)")
    p.add_argument("--retries", type=int, default=2, help="extra attempts after a failed read (default 2)")


def _bus(args) -> SerialServoBus:
    return SerialServoBus(BusConfig(args.port, timeout_s=args.timeout, retries=args.retries, echo=args.echo))


def cmd_emulate(args) -> int:
    from hardware.emulator import EmulatorConfig, Faults, ServoEmulator  # POSIX only (pty): imported when used

    faults = Faults(
        drop_rate=args.drop_rate,
        corrupt_rate=args.corrupt_rate,
        missing_ids=frozenset(_ids(args.missing)),
        stuck_ids=frozenset(_ids(args.stuck)),
        hot_ids=frozenset(_ids(args.hot)),
    )
    dups = tuple(_ids(args.duplicate))
    with ServoEmulator(_ids(args.ids), EmulatorConfig(echo=args.echo), faults, duplicate_ids=dups) as emu:
        print(emu.port, flush=True)
        print(f"{len(emu.servos)} virtual servos; Ctrl-C to stop", file=sys.stderr, flush=True)
        try:
            while True:
                time.sleep(0.5)
        except KeyboardInterrupt:
            print(f"stopped after {emu.packets_seen} packets", file=sys.stderr)
    return 0


def cmd_scan(args) -> int:
    expected = load_calibration(args.calibration, load_hand()).ids if args.calibration else []
    with _bus(args) as bus:
        report = scan(bus, _ids(args.ids), expected)
    print(f"present: {report.present or 'none'}")
    if report.duplicates:
        print(f"DUPLICATE IDs (two servos answer at once): {report.duplicates}: give one of each a new ID")
    if report.missing:
        print(f"missing from the calibration: {report.missing}")
    return 1 if report.duplicates or report.missing else 0


def cmd_calibrate(args) -> int:
    hand = load_hand()
    start = load_calibration(args.start, hand) if args.start else default_calibration(hand)
    with _bus(args) as bus:
        wiz = CalibrationWizard(bus, hand, start)
        print("commands: + - 'step N' free hold set skip   (empty line = set)")
        print(wiz.prompt())
        for line in sys.stdin:
            try:
                print(wiz.execute(line))
            except ValueError as e:
                print(f"? {e}")
            if wiz.finished:
                break
        if not wiz.finished:
            print("input ended before every joint was calibrated; nothing saved", file=sys.stderr)
            return 1
        for note in wiz.notes:
            print(f"note: {note}")
        save_calibration(wiz.result(), args.out)
    print(f"saved {args.out}")
    return 0


def cmd_play(args) -> int:
    from studio.motion.show import load_show

    hand = load_hand()
    cal = load_calibration(args.calibration, hand)
    show = load_show(args.show, hand)
    cfg = PlayerConfig(hold_torque_on_stop=not args.release_on_stop)
    with contextlib.ExitStack() as stack:
        if args.dry_run:
            from hardware.emulator import ServoEmulator  # POSIX only (pty): imported when used

            emu = stack.enter_context(ServoEmulator(cal.ids))
            args.port = emu.port
            print(f"dry run: playing to the emulator on {emu.port}")
        elif not args.port:
            raise ValueError("give --port PATH (or --dry-run to play to the emulator)")
        bus = stack.enter_context(_bus(args))
        print(f"playing {show.title!r}: {show.duration:.2f} s, {len(show.times)} samples; Ctrl-C stops safely")
        result = Player(bus, cal, cfg).play(show.times, show.positions, show.joint_names)
    late = np.abs(result.lateness_s) * 1000
    clipped = int(result.clipped_limit.any(1).sum() + result.clipped_step.any(1).sum())
    print(f"{result.reason.value}: {result.message}; torque {result.torque}")
    if len(late):
        print(
            f"{len(result.sent)} ticks (ramp {result.ramp_ticks}), {result.commands} commands, tick jitter p50 "
            f"{np.percentile(late, 50):.2f} ms p99 {np.percentile(late, 99):.2f} ms, {clipped} ticks clipped, "
            f"max tracking error {result.max_tracking_error_rad:.3f} rad"
        )
    if args.log:
        np.savez(
            args.log, t=result.t, requested=result.requested, sent=result.sent, measured_t=result.measured_t,
            measured_joint=result.measured_joint, measured_rad=result.measured_rad, joint_names=result.joint_names,
        )  # fmt: skip
        print(f"command vs measured saved to {args.log}")
    return 0 if result.ok else 1


def cmd_jog(args) -> int:
    hand = load_hand()
    cal = load_calibration(args.calibration, hand)
    with _bus(args) as bus:
        jog = Jog(bus, cal, home_pose=hand.rest_pose())
        print(HELP)
        print(jog.status())
        try:
            for line in sys.stdin:
                if line.strip().lower() in ("q", "quit", "exit"):
                    break
                try:
                    print(jog.execute(line))
                except ValueError as e:
                    print(f"? {e}")
        except KeyboardInterrupt:
            jog.estop()
            print("E-STOP (Ctrl-C): servos halted")
    return 0


def register(sub) -> None:
    p = sub.add_parser("emulate", help="run 21 virtual LX-15D servos on a pseudo-terminal until Ctrl-C")
    p.add_argument("--ids", default="1-21", help="servo IDs present (default 1-21)")
    p.add_argument("--echo", action="store_true", help="echo the host's bytes like a single-wire adapter")
    p.add_argument("--drop-rate", type=float, default=0.0, help="probability of dropping an answer")
    p.add_argument("--corrupt-rate", type=float, default=0.0, help="probability of corrupting an answer")
    p.add_argument("--missing", default="", help="IDs that do not answer, e.g. 5,7")
    p.add_argument("--stuck", default="", help="IDs with a locked rotor")
    p.add_argument("--hot", default="", help="IDs that report over-temperature")
    p.add_argument("--duplicate", default="", help="IDs that a second servo also uses")
    p.set_defaults(func=cmd_emulate)

    p = sub.add_parser("scan", help="find the servos on a bus and flag duplicate IDs")
    _bus_args(p)
    p.add_argument("--ids", default="0-253", help="IDs to try (default 0-253)")
    p.add_argument("--calibration", type=Path, help="also report the calibration's servos that do not answer")
    p.set_defaults(func=cmd_scan, retries=0)

    p = sub.add_parser("calibrate", help="set each joint's zero and limits by jogging (reads commands on stdin)")
    _bus_args(p)
    p.add_argument("--out", type=Path, required=True, help="calibration YAML to write")
    p.add_argument("--start", type=Path, help="calibration to start from (IDs, values for 'skip'); default IDs 1-21")
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("play", help="play a show file on the servos at 40 Hz with safety stops")
    p.add_argument("show", type=Path, help="show file (.json)")
    _bus_args(p, port_required=False)
    p.add_argument("--calibration", type=Path, help="calibration YAML (default: assets/calibration.yaml)")
    p.add_argument("--dry-run", action="store_true", help="play to a built-in emulator instead of --port")
    p.add_argument("--release-on-stop", action="store_true", help="release torque when stopped early")
    p.add_argument("--log", type=Path, help="save command vs measured positions to this .npz")
    p.set_defaults(func=cmd_play)

    p = sub.add_parser("jog", help="move joints one at a time from the terminal (type help)")
    _bus_args(p)
    p.add_argument("--calibration", type=Path, help="calibration YAML (default: assets/calibration.yaml)")
    p.set_defaults(func=cmd_jog)
