"""Calibrate the rig: play known poses, photograph their shadows, fit the rig, keep it in the calibration file.

The one engine function of ``shadow-studio calibrate-rig`` and the notebook's Rig panel::

    result = calibrate_rig(session.bus, cal, camera, RigCalibrationConfig(), out=Path("rig-cal"))
    result.summary   # the fitted values (rig-file keys) + iou_loss_before / iou_loss_after / seconds

Steps: :func:`studio.learn.rig_fit.calibration_poses` (collision-free, reaching towards the light) →
:func:`studio.project.capture.capture_poses` → :func:`studio.learn.rig_fit.fit_rig` from the calibration's rig →
outputs in ``out``: ``calibration.yaml`` (the servo map with the measured rig in its ``rig`` section), ``captures/``
(the photographed shadows as a capture set, for fine-tuning), ``rig_fit.json`` (the summary), ``compare.png``
(each pose: photograph | captured | simulated before | after). Every file is written atomically; the starting
calibration file is never overwritten.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from hardware.calibration import Calibration, save_calibration
from hardware.camera import Camera
from studio.atomic import write_bytes, write_json
from studio.errors import ProgressFn
from studio.learn.captures import CaptureSet, save_captures
from studio.learn.rig_fit import RigFit, RigFitConfig, calibration_poses, fit_rig
from studio.project.capture import CaptureConfig, Captures, capture_poses
from studio.review.real_vs_sim import compare_sheet
from studio.sim.backdrop import BackdropLayout
from studio.sim.hand import Hand, load_hand
from studio.sim.rig_file import rig_to_mapping
from studio.sim.roll import file_deg
from studio.sim.shadow import Rig, ShadowRenderer

log = logging.getLogger(__name__)


# Captures for calibration at 384² of the 0.6 m window (1.6 mm a pixel, as fine as a 960-pixel camera sees a 1.6 m
# view): measured on an oblique, blurred, unevenly lit virtual camera, 256² pulled the light's distance 4-8 % long and
# the foam 0.1 mm thick; 384² (drawn at 2×) 1-2 % and 0.01 mm, for the same fitting time as 256² drawn at 3×.
CALIBRATION_CAPTURE = CaptureConfig(resolution=384)


@dataclass(frozen=True)
class RigCalibrationConfig:
    """What a rig calibration does."""

    poses: int = 12  # known poses played and photographed [3, 200]
    seed: int = 0  # which calibration poses (the same seed plays the same poses) [0, 4294967295]
    capture: CaptureConfig = field(default_factory=lambda: CALIBRATION_CAPTURE)  # how each pose is captured
    fit: RigFitConfig = field(default_factory=RigFitConfig)  # how the rig is fitted

    def __post_init__(self) -> None:
        if not 3 <= self.poses <= 200:
            raise ValueError(f"calibrate with 3..200 poses, got {self.poses}")


@dataclass
class RigCalibration:
    """The outcome: the fit, what was captured, the calibration with the measured rig, the summary."""

    fit: RigFit  # rig before and after, losses
    captures: Captures  # the photographed shadows and the measured poses
    calibration: Calibration  # the starting calibration with the measured rig recorded
    summary: dict  # rig-file keys of the fitted rig + iou_loss_before, iou_loss_after, seconds, poses
    files: dict[str, Path] = field(default_factory=dict)  # what was written, by name


def summary_of(fit: RigFit, seconds: float, poses: int) -> dict:
    """The JSON summary: the fitted rig's values under the rig-file keys, the losses, the time."""
    return rig_to_mapping(fit.after) | {
        "iou_loss_before": round(fit.loss_before, 5),
        "iou_loss_after": round(fit.loss_after, 5),
        "seconds": round(seconds, 2),
        "poses": poses,
        "evaluations": fit.evaluations,
        "camera_blur_px": round(fit.blur_px, 3),
    }


def calibrate_rig(
    bus,
    calibration: Calibration,
    camera: Camera,
    cfg: RigCalibrationConfig | None = None,
    start: Rig | None = None,
    out: Path | None = None,
    layout: BackdropLayout | None = None,
    hand: Hand | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    H_backdrop_camera: np.ndarray | None = None,
) -> RigCalibration:
    """Capture ``cfg.poses`` known poses on ``bus`` with ``camera`` and fit the rig from ``start`` (default: the
    rig ``calibration`` records). The backdrop is found from ``layout``'s markers in every photograph, or given as
    ``H_backdrop_camera (3, 3)`` (four clicked corners). Progress: stage ``"capture"`` (poses), then ``"fit"``;
    ``cancel`` stops between poses or fit steps (:class:`~studio.errors.Cancelled`). Writes ``out``'s files when
    ``out`` is given."""
    cfg = cfg or RigCalibrationConfig()
    hand = hand or load_hand()
    start = (start or calibration.rig()).with_resolution(cfg.capture.resolution)
    t0 = time.perf_counter()
    poses = calibration_poses(hand, cfg.poses, cfg.seed)
    caught = capture_poses(bus, calibration, camera, poses, start.window, cfg.capture, layout, H_backdrop_camera,
                           progress, cancel)  # fmt: skip
    fit = fit_rig(caught.theta, caught.coverage, start, cfg.fit, hand, progress, cancel)
    seconds = time.perf_counter() - t0
    measured = {k: v for k, v in rig_to_mapping(fit.after).items() if k != "mount_roll_deg"}
    new_cal = replace(calibration, roll=fit.after.roll, measured=measured)
    result = RigCalibration(fit, caught, new_cal, summary_of(fit, seconds, len(poses)))
    log.info("rig calibrated from %d poses in %.1f s: window IoU loss %.4f -> %.4f", len(poses), seconds,
             fit.loss_before, fit.loss_after)  # fmt: skip
    if out is not None:
        result.files = write_outputs(result, Path(out), hand, cfg)
    return result


def write_outputs(result: RigCalibration, out: Path, hand: Hand, cfg: RigCalibrationConfig) -> dict[str, Path]:
    """``calibration.yaml``, ``captures/``, ``compare.png`` and ``rig_fit.json`` in ``out`` (made if needed)."""
    import cv2

    out.mkdir(parents=True, exist_ok=True)
    fit, caught = result.fit, result.captures
    files = {"calibration": out / "calibration.yaml", "captures": out / "captures", "compare": out / "compare.png",
             "summary": out / "rig_fit.json"}  # fmt: skip
    save_calibration(result.calibration, files["calibration"])
    rig = fit.after.with_resolution(caught.coverage.shape[1])  # the set's rig: the measured one (fine-tuning keeps it)
    cs = CaptureSet(caught.theta, caught.masks, caught.t, rig.to_dict(), hand.hash,
                    source="calibrate-rig: calibration poses photographed on the rig")  # fmt: skip
    save_captures(files["captures"], cs)
    before = ShadowRenderer(hand, fit.before).render(caught.theta, check=False)
    after = ShadowRenderer(hand, fit.after).render(caught.theta, check=False)
    sheet = compare_sheet(caught.photos, caught.masks, before, after)
    ok, png = cv2.imencode(".png", sheet)
    if ok:
        write_bytes(files["compare"], png.tobytes())
    record = result.summary | {
        "rig_before": fit.before.to_dict(), "rig_after": fit.after.to_dict(),
        "roll_deg_before": file_deg(fit.before.roll), "per_pose_iou_loss_after": list(fit.per_pose_after),
        "config": asdict(cfg), "commanded": np.round(caught.commanded, 6).tolist(),
        "measured": np.round(caught.theta, 6).tolist(),
    }  # fmt: skip
    write_json(files["summary"], record)
    return files
