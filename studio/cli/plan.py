"""Verbs ``plan``, ``validate``, ``show-info`` and ``export-csv``: the face of ``studio.motion``."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from studio.cli.flags import add_config_flags, config_from_args
from studio.cli.progress import add_quiet_flag
from studio.errors import count, report
from studio.motion.limits import LimitsConfig
from studio.motion.path import PathConfig
from studio.motion.plan import PlanConfig, load_keyframes, plan_show
from studio.motion.show import export_csv, load_show, save_show
from studio.motion.show_info import show_info_lines
from studio.motion.timing import TimingConfig
from studio.sim.hand import load_hand
from studio.targets.path_checks import check_outputs


def _plan(args: argparse.Namespace) -> int:
    from studio.cli.progress import ctrl_c_cancels
    from studio.jobs.bars import TqdmBars

    check_outputs([args.out, args.csv], inputs=[args.poses, args.urdf])
    with TqdmBars(disable=args.quiet) as bars:
        report(bars, "read keyframes")  # a bar within a second, whatever the file's size
        hand = load_hand(args.urdf)
        kf = load_keyframes(args.poses, hand)
        base = PlanConfig()
        cfg = dataclasses.replace(
            base,
            limits=config_from_args(args, LimitsConfig, base=base.limits),
            path=config_from_args(args, PathConfig, base=base.path),
            timing=config_from_args(args, TimingConfig, base=base.timing),
        )
        with ctrl_c_cancels() as cancel:
            result = plan_show(hand, kf, cfg, title=args.title, progress=bars, cancel=cancel)
    out = save_show(result.show, args.out, hand)
    for seg in result.trajectory.late:
        print(f"warning: {seg.describe()}; stretched, later keyframes are late by the difference")
    s = result.show
    if len(s.times) == 1:
        print("one keyframe at t = 0: the show holds that pose (no home move; a player ramps the hand to it first)")
    print(
        f"planned {count(len(s.keyframes), 'keyframe')}"
        f"{' (+ home at t = 0)' if result.home_added else ''}: "
        f"{s.duration:.3f} s, {len(s.times)} samples at {s.rate_hz:g} Hz, "
        f"{int(result.path.repaired.sum())} path points repaired, {int(result.path.refined.sum())} fingertip-refined, "
        f"{result.collision_checks} collision checks, max jerk {result.max_jerk_ratio:.0%} of its limit"
    )
    print(f"wrote {out}")
    if args.csv:
        print(f"wrote {export_csv(result.show, args.csv)}")
    return 0


def _validate(args: argparse.Namespace) -> int:
    show = load_show(args.show, load_hand(args.urdf))
    print(f"{args.show}: valid show, version {show.format_version}, {len(show.times)} samples, {show.duration:.3f} s")
    return 0


def _info(args: argparse.Namespace) -> int:
    from hardware.calibration import load_calibration
    from hardware.show_checks import soft_limit_summary

    hand = load_hand(args.urdf)
    show = load_show(args.show, hand)
    cal = load_calibration(args.calibration, hand)  # what `play` would play it on (default: the shipped one)
    limits = soft_limit_summary(show.positions, show.joint_names, cal)
    print("\n".join([*show_info_lines(show), f"limits:       {limits}"]))
    return 0


def _csv(args: argparse.Namespace) -> int:
    check_outputs([args.out], inputs=[args.show, args.urdf])
    show = load_show(args.show, load_hand(args.urdf))
    print(f"wrote {export_csv(show, args.out, degrees=args.degrees)}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add the motion verbs to ``shadow-studio``."""
    p = sub.add_parser("plan", help="plan a collision-free, jerk-limited show through keyframes (POSES.json)")
    p.add_argument("poses", type=Path, help='keyframes: {"keyframes": [{"t": s, "pose": {joint: rad}}, ...]}')
    p.add_argument("--out", type=Path, required=True, help="show file to write (JSON)")
    p.add_argument("--title", default=None, help="show title (default: the keyframes file's, else 'untitled')")
    p.add_argument("--csv", type=Path, default=None, help="also export the samples as CSV")
    add_config_flags(p, TimingConfig, ("allow_late",))
    add_config_flags(p, LimitsConfig, ("velocity_scale", "acceleration", "jerk"))
    add_config_flags(p, PathConfig, ("seed",))
    p.add_argument("--urdf", type=Path, default=None, help="hand URDF (default: the shipped hand)")
    add_quiet_flag(p)
    p.set_defaults(func=_plan)

    for name, fn, text in (("validate", _validate, "check a show file"), ("show-info", _info, "describe a show")):
        p = sub.add_parser(name, help=text)
        p.add_argument("show", type=Path, help="show file (JSON)")
        p.add_argument("--urdf", type=Path, default=None, help="hand URDF (default: the shipped hand)")
        if name == "show-info":  # its last line: the joints this calibration's soft limits stop, as `play` says
            p.add_argument("--calibration", type=Path, default=None,
                           help="calibration YAML it would play on (default: assets/calibration.yaml)")  # fmt: skip
        p.set_defaults(func=fn)

    p = sub.add_parser("export-csv", help="export a show's samples as CSV (t, one column per joint)")
    p.add_argument("show", type=Path, help="show file (JSON)")
    p.add_argument("--out", type=Path, required=True, help="CSV file to write")
    p.add_argument("--degrees", action="store_true", help="angles in degrees instead of radians")
    p.add_argument("--urdf", type=Path, default=None, help="hand URDF (default: the shipped hand)")
    p.set_defaults(func=_csv)
