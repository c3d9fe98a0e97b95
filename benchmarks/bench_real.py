"""The real rig in the loop, on the virtual camera: calibrate the rig, then learn from its real shadows.

The servo emulator plays the hand; :class:`hardware.virtual_camera.VirtualCamera` photographs the emulator's
measured pose through the rig of ``--true-rig`` (a YAML of ``studio.sim.rig_file``'s keys, with its camera), as a
real camera behind the backdrop would. Three steps, each through the engine the verbs use:

1. **Calibrate** (``calibrate-rig``'s :func:`studio.project.rig_calibration.calibrate_rig`, 12 poses): the fitted
   light distance, roll and foam against the true rig's (the reference), the captured-vs-simulated window IoU loss
   before and after, the seconds.
2. **Capture** (``capture``'s :func:`studio.project.capture.capture_walk`): ``--pairs`` (pose, shadow) pairs along
   one seeded walk for training, ``--held-out`` along another (held out whole: a walk's neighbours are alike), both
   rectified into the calibrated rig.
3. **Fine-tune** (``finetune``'s :func:`studio.learn.finetune.finetune`) the shipped simulation-only self-model on
   them: its held-out MAE before (the reference) and after, and their ratio.

Prints each step's figures, then, last, one JSON line with ``mae_sim_only``, ``mae_finetuned``, ``mae_ratio``,
``pairs_train``, ``pairs_held_out``, and the calibration's ``light_error_pct``, ``roll_error_deg``,
``foam_error_mm``, ``iou_loss_before``, ``iou_loss_after``, ``calibration_seconds``.

    python benchmarks/bench_real.py --true-rig benchmarks/rigs/light_near_rolled.yaml [--pairs 600]
                                    [--held-out 150] [--steps 400] [--out runs/bench_real]
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--true-rig", type=Path, default=ROOT / "benchmarks" / "rigs" / "light_near_rolled.yaml")
    p.add_argument("--pairs", type=int, default=600, help="training pairs to capture (≤ 2,000)")
    p.add_argument("--held-out", type=int, default=150, help="held-out pairs to capture (another walk)")
    p.add_argument("--poses", type=int, default=12, help="calibration poses")
    p.add_argument("--steps", type=int, default=400, help="fine-tuning steps")
    p.add_argument("--out", type=Path, default=ROOT / "runs" / "bench_real")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)

    from hardware.calibration import load_calibration
    from hardware.camera import Camera
    from hardware.session import ServoSession
    from hardware.virtual_camera import VirtualCamera, emulator_angles
    from studio.learn.finetune import FinetuneConfig, finetune
    from studio.project.capture import CaptureConfig, capture_walk
    from studio.project.rig_calibration import RigCalibrationConfig, calibrate_rig
    from studio.sim.hand import load_hand
    from studio.sim.photo import CameraModel
    from studio.sim.rig_file import read_rig_file

    true, camera_dict = read_rig_file(args.true_rig)
    hand = load_hand()
    cal = load_calibration(None, hand)
    if args.out.exists():
        shutil.rmtree(args.out)
    args.out.mkdir(parents=True)
    with ServoSession(calibration=cal) as session:
        angles = emulator_angles(session.emulator, cal)
        with Camera(VirtualCamera(angles, true, CameraModel.from_dict(camera_dict))) as camera:
            result = calibrate_rig(session.bus, cal, camera, RigCalibrationConfig(poses=args.poses),
                                   out=args.out / "calibration", hand=hand)  # fmt: skip
            fitted = result.fit.after
            calibrated = result.calibration
            cfg = CaptureConfig(resolution=128, settle_s=0.1)
            t0 = time.perf_counter()
            capture_walk(session.bus, calibrated, camera, args.pairs, args.out / "train", cfg, seed=0)
            capture_walk(session.bus, calibrated, camera, args.held_out, args.out / "held_out", cfg, seed=1)
            capture_seconds = time.perf_counter() - t0
    s = result.summary
    figures = {
        "light_error_pct": round(100 * (fitted.light[2] / true.light[2] - 1), 2),
        "roll_error_deg": round(math.degrees(fitted.roll - true.roll), 3),
        "foam_error_mm": round(1000 * (fitted.foam - true.foam), 3),
        "backdrop_error_pct": round(100 * (fitted.backdrop_z / true.backdrop_z - 1), 2),
        "iou_loss_before": s["iou_loss_before"],
        "iou_loss_after": s["iou_loss_after"],
        "calibration_seconds": s["seconds"],
    }
    print(f"calibration ({args.poses} poses, {s['seconds']:.1f} s): light {fitted.light[2]:.3f} m (true "
          f"{true.light[2]:.3f}, {figures['light_error_pct']:+.2f} %), roll {math.degrees(fitted.roll):.2f}° (true "
          f"{math.degrees(true.roll):.2f}°), foam {1000 * fitted.foam:.2f} mm (true {1000 * true.foam:.2f}); window "
          f"IoU loss {s['iou_loss_before']:.4f} -> {s['iou_loss_after']:.4f} "
          f"({s['iou_loss_after'] / s['iou_loss_before']:.3f}×)")  # fmt: skip
    print(f"captured {args.pairs} + {args.held_out} pairs in {capture_seconds:.1f} s")
    ft = finetune(FinetuneConfig(captures=str(args.out / "train"), held_out=str(args.out / "held_out"),
                                 out=str(args.out / "finetuned.pt"), steps=args.steps), hand)  # fmt: skip
    ratio = ft["mae_finetuned"] / ft["mae_sim_only"]
    print(f"fine-tuned in {ft['seconds']:.1f} s: held-out MAE {ft['mae_sim_only']:.5f} (simulation only) -> "
          f"{ft['mae_finetuned']:.5f} ({ratio:.3f}×, {100 * (1 - ratio):.1f} % lower)")  # fmt: skip
    record = {"mae_sim_only": round(ft["mae_sim_only"], 6), "mae_finetuned": round(ft["mae_finetuned"], 6),
              "mae_ratio": round(ratio, 4), "pairs_train": ft["pairs_train"], "pairs_held_out": ft["pairs_held_out"],
              "capture_seconds": round(capture_seconds, 1), "finetune_seconds": ft["seconds"], **figures}  # fmt: skip
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
