"""``shadow-studio calibrate-rig`` (play known poses, photograph their shadows, fit the rig, save it) and
``shadow-studio capture`` (photograph the shadow at many poses: pairs to fine-tune the self-model on).

::

    shadow-studio calibrate-rig --camera 0 --port /dev/ttyUSB0 --calibration cal.yaml --out rig-cal
    shadow-studio calibrate-rig --camera virtual --true-rig RIG.yaml --emulator --out rig-cal
    shadow-studio capture --camera 0 --port /dev/ttyUSB0 --calibration rig-cal/calibration.yaml --out caps

``--camera`` is a device index, a video file or frame folder, or ``virtual``: the servo emulator's measured angles
rendered through the rig of ``--true-rig`` (a YAML of ``studio.sim.rig_file``'s keys, with an optional ``camera``)
and photographed (:class:`hardware.virtual_camera.VirtualCamera`); the virtual camera needs ``--emulator``. The
engine is :func:`studio.project.rig_calibration.calibrate_rig` (the Rig panel's too). It prints, last, one JSON line:
the fitted ``light_distance_m``, ``backdrop_distance_m``, ``hand_offset_m``, ``mount_roll_deg``, ``foam_mm``,
``iou_loss_before``, ``iou_loss_after``, ``seconds``; ``capture`` (:func:`studio.project.capture.capture_walk`)
prints ``captures``, ``pairs``, ``seconds``. The servos stop and hold however it ends (the session's
fail-safe close); Ctrl-C, SIGTERM and SIGHUP end it with the signal's exit code.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np

from studio.cli.flags import add_config_flags, config_from_args, ranged
from studio.cli.progress import add_quiet_flag


def _corners(text: str) -> list[float]:
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 8:
        raise argparse.ArgumentTypeError("--corners takes 8 numbers: x,y of the window's top-left, top-right, "
                                         "bottom-right and bottom-left corners in the camera image")  # fmt: skip
    return values


def open_camera(source: str, session, calibration, true_rig: Path | None):
    """The camera ``source`` names, not yet open (:func:`studio.project.capture.open_camera_source`), after the
    flags that go with ``virtual`` are checked in the command line's words."""
    from studio.project.capture import open_camera_source

    if source.strip() != "virtual" and true_rig is not None:
        raise ValueError("--true-rig describes the virtual camera's world: use it with --camera virtual")
    if source.strip() == "virtual" and true_rig is None:
        raise ValueError("--camera virtual needs --true-rig RIG.yaml: the rig as it really is, which it photographs")
    if source.strip() == "virtual" and session.emulator is None:
        raise ValueError("--camera virtual photographs the servo emulator's hand: add --emulator")
    return open_camera_source(source, session.emulator, calibration, true_rig)


def _check_out(out: Path, force: bool) -> None:
    if out.exists() and any(out.iterdir()) and not force:
        raise ValueError(f"{out} is not empty: choose another --out or pass --force to write over its files")


@contextmanager
def _servos_and_camera(args: argparse.Namespace, verb: str) -> Iterator[tuple]:
    """``(session, camera, calibration, H_backdrop_camera or None, progress bars)`` for a verb that photographs the
    hand: the e-stop checked before the port opens, signals ending it safely, everything closed however it ends."""
    from hardware.calibration import load_calibration
    from hardware.estop import check_not_latched
    from studio.cli.servos import session_for
    from studio.cli.signals import stop_on_signals
    from studio.jobs.bars import TqdmBars
    from studio.sim.hand import load_hand
    from studio.targets.backdrop import backdrop_from_corners

    cal = load_calibration(args.calibration, load_hand())
    if not args.emulator and not args.port:
        raise ValueError("give --port PATH (the servo adapter) or --emulator")
    check_not_latched(args.port or "the emulator")
    H = None if args.corners is None else backdrop_from_corners(np.reshape(args.corners, (4, 2)), cal.rig().window)
    with ExitStack() as stack:
        stack.enter_context(stop_on_signals(verb))
        session = stack.enter_context(session_for(args, cal, args.emulator))
        camera = stack.enter_context(open_camera(args.camera, session, cal, args.true_rig))
        yield session, camera, cal, H, stack.enter_context(TqdmBars(disable=args.quiet))


def cmd_calibrate_rig(args: argparse.Namespace) -> int:
    from studio.learn.rig_fit import RigFitConfig
    from studio.project.capture import CaptureConfig
    from studio.project.rig_calibration import CALIBRATION_CAPTURE, RigCalibrationConfig, calibrate_rig

    fit = config_from_args(args, RigFitConfig, base=RigFitConfig(fit=tuple(args.fit.split(","))))
    capture = config_from_args(args, CaptureConfig, base=CALIBRATION_CAPTURE)
    cfg = config_from_args(args, RigCalibrationConfig, capture=capture, fit=fit)
    _check_out(args.out, args.force)
    with _servos_and_camera(args, "calibrate-rig") as (session, camera, cal, H, bars):
        result = calibrate_rig(session.bus, cal, camera, cfg, None, args.out, progress=bars, H_backdrop_camera=H)
    s = result.summary
    print(f"window IoU loss {s['iou_loss_before']:.4f} -> {s['iou_loss_after']:.4f} over {s['poses']} poses "
          f"in {s['seconds']:.1f} s; rig saved in {result.files['calibration']}")  # fmt: skip
    print(json.dumps(s))
    return 0


def cmd_capture(args: argparse.Namespace) -> int:
    import time

    from studio.project.capture import CaptureConfig, capture_walk

    cfg = config_from_args(args, CaptureConfig, base=CaptureConfig(resolution=128, settle_s=0.1))
    t0 = time.perf_counter()
    with _servos_and_camera(args, "capture") as (session, camera, cal, H, bars):
        cs = capture_walk(session.bus, cal, camera, args.pairs, args.out, cfg, args.step, args.seed,
                          H_backdrop_camera=H, progress=bars)  # fmt: skip
    seconds = time.perf_counter() - t0
    print(f"{len(cs)} captured pairs in {args.out} ({seconds:.1f} s); fine-tune with: shadow-studio finetune "
          f"--captures {args.out} --out MODEL.pt")  # fmt: skip
    print(json.dumps({"captures": str(args.out), "pairs": len(cs), "seconds": round(seconds, 2)}))
    return 0


def _photographing_args(p: argparse.ArgumentParser) -> None:
    from studio.cli.servos import bus_args

    p.add_argument("--camera", required=True, help="camera index, video file or frame folder, or 'virtual'")
    p.add_argument("--true-rig", type=Path, help="the virtual camera's rig as it really is (YAML)")
    p.add_argument("--emulator", action="store_true", help="play to the built-in servo emulator instead of --port")
    bus_args(p, port_required=False)
    p.add_argument("--calibration", type=Path, help="servo calibration (and measured rig; default: the shipped one)")
    p.add_argument("--corners", type=_corners, help="no markers: the window's 4 corners in the image, x,y ×4")
    add_quiet_flag(p)


def register(sub: argparse._SubParsersAction) -> None:
    from studio.learn.rig_fit import PARAMETERS, RigFitConfig
    from studio.project.capture import CaptureConfig
    from studio.project.rig_calibration import CALIBRATION_CAPTURE, RigCalibrationConfig

    p = sub.add_parser("calibrate-rig", help="measure the rig (light, backdrop, mount, roll, foam) with a camera")
    _photographing_args(p)
    p.add_argument("--out", type=Path, required=True, help="folder for calibration.yaml, captures/, compare.png")
    p.add_argument("--force", action="store_true", help="write into a non-empty --out")
    p.add_argument("--fit", default=",".join(PARAMETERS), help=f"parameters to fit (default: all of "
                   f"{','.join(PARAMETERS)})")  # fmt: skip
    add_config_flags(p, RigCalibrationConfig, ("poses", "seed"))
    add_config_flags(p, CaptureConfig, base=CALIBRATION_CAPTURE)
    add_config_flags(p, RigFitConfig, ("supersample", "max_evals"))
    p.set_defaults(func=cmd_calibrate_rig)

    p = sub.add_parser("capture", help="photograph the hand's shadow at many poses: pairs to fine-tune on")
    _photographing_args(p)
    p.add_argument("--out", type=Path, required=True, help="capture set folder (continued when it holds one)")
    p.add_argument("--pairs", type=ranged(int, "[1, 100000]"), default=500, help="pairs to capture (default 500)")
    p.add_argument("--step", type=ranged(float, "(0, 3.2]"), default=0.25, metavar="RAD",
                   help="largest joint move between poses, rad (default 0.25)")  # fmt: skip
    p.add_argument("--seed", type=ranged(int, "[0, 4294967295]"), default=0, help="the walk's seed (default 0)")
    add_config_flags(p, CaptureConfig, base=CaptureConfig(resolution=128, settle_s=0.1))
    p.set_defaults(func=cmd_capture)
