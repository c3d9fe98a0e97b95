"""Capture the real shadow of known poses: play each pose on the hand, wait till it stands, read it back, photograph.

The one capture step every face uses (``calibrate-rig``, the Rig panel, ``capture`` for fine-tuning data): a pose
goes to the servos through :class:`hardware.jog.Jog` (clipped to the soft limits, paced at ``speed_rad_s``), the
capture waits for the move's time plus ``settle_s``, reads the hand back (the **measured** angles are what the
shadow shows, not the commanded ones), then takes the first camera frame newer than that read, finds the backdrop in
it (its ArUco markers, or a fixed homography from four clicked corners) and rectifies the shadow into the rig's window
as coverage in [0, 1] (the calibration's input) and as a mask (1 = shadow, the project's convention).

IO lives here (servos, camera); the image work is :mod:`studio.targets.backdrop`'s pure compute.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hardware.calibration import Calibration
from hardware.camera import Camera
from hardware.jog import Jog, JogConfig
from studio.errors import Cancelled, ProgressFn, report
from studio.learn.captures import CaptureRecorder, CaptureSet
from studio.sim.backdrop import BackdropLayout
from studio.sim.hand import load_hand
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import walk_poses
from studio.targets.backdrop import find_backdrop, rectify, shadow_coverage

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class CaptureConfig:
    """How poses are captured."""

    resolution: int = 256  # window pixels per side of each capture [32, 2048]
    settle_s: float = 0.3  # wait after a move's time before reading the hand back, s [0, 10]
    speed_rad_s: float = 2.5  # joint speed of the moves between poses, rad/s: half the URDF's 5.2 (0, 5.2]
    frame_timeout_s: float = 3.0  # a camera that gives no newer frame within this is stalled, s (0, 60]

    def __post_init__(self) -> None:
        if not 32 <= self.resolution <= 2048:
            raise ValueError(f"capture resolution must be within 32..2048 pixels, got {self.resolution}")
        if not (0 <= self.settle_s <= 10 and 0 < self.speed_rad_s <= 5.2 and 0 < self.frame_timeout_s <= 60):
            raise ValueError("settle_s must be within 0..10 s, speed_rad_s within 0..5.2 rad/s, frame_timeout_s > 0")


@dataclass
class Captures:
    """What a capture run saw: ``N`` poses played, their measured angles and rectified shadows."""

    commanded: np.ndarray  # (N, 21) rad, the poses sent (after clipping to the soft limits)
    theta: np.ndarray  # (N, 21) rad, the poses read back from the servos (what the camera saw)
    coverage: np.ndarray  # (N, R, R) float32 in [0, 1], each window pixel's share in shadow
    t: np.ndarray  # (N,) time.monotonic() of each photograph, s
    photos: list[np.ndarray] = field(default_factory=list)  # (H, W, 3) uint8 BGR photographs, one per pose
    H_backdrop_camera: np.ndarray | None = None  # (3, 3) the last homography camera pixels → backdrop metres

    @property
    def masks(self) -> np.ndarray:
        """``(N, R, R)`` uint8, 1 = shadow: the coverage thresholded at one half."""
        return (self.coverage >= 0.5).astype(np.uint8)

    def __len__(self) -> int:
        return len(self.theta)


def _sleep(seconds: float, cancel: threading.Event | None) -> None:
    if cancel is None:
        time.sleep(seconds)
    elif cancel.wait(seconds):
        raise Cancelled("the capture was cancelled")


def capture_poses(
    bus,
    calibration: Calibration,
    camera: Camera,
    poses: np.ndarray,
    window_m: float,
    cfg: CaptureConfig | None = None,
    layout: BackdropLayout | None = None,
    H_backdrop_camera: np.ndarray | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    keep_photos: bool = True,
    on_capture: Callable[[np.ndarray, np.ndarray, float], None] | None = None,
) -> Captures:
    """Play each of ``poses (N, 21)`` rad (hand order) on ``bus`` and photograph its shadow with ``camera``.

    The backdrop is found in every photograph from ``layout``'s markers unless ``H_backdrop_camera (3, 3)`` (from
    four clicked corners) is given. Progress ``("capture", done, N)``; ``cancel`` raises
    :class:`~studio.errors.Cancelled` between poses (the servos hold the last pose; the caller's session stops them).
    ``on_capture(theta (21,), coverage (R, R), t)`` sees each capture as it is made (a recorder saving as it goes).
    """
    cfg = cfg or CaptureConfig()
    layout = layout or BackdropLayout()
    poses = np.atleast_2d(np.asarray(poses, dtype=np.float64))
    jog = Jog(bus, calibration, config=JogConfig(speed_rad_s=cfg.speed_rad_s))
    jog.target = np.clip(jog.read_array(strict=False), calibration.lower, calibration.upper)  # paced from here
    n, res = len(poses), cfg.resolution
    out = Captures(np.zeros((n, poses.shape[1])), np.zeros((n, poses.shape[1])), np.zeros((n, res, res), np.float32),
                   np.zeros(n))  # fmt: skip
    for i, pose in enumerate(poses):
        if cancel is not None and cancel.is_set():
            raise Cancelled("the capture was cancelled")
        move = jog.go_pose(pose)
        _sleep(move.duration_s + cfg.settle_s, cancel)
        out.commanded[i] = jog.target
        out.theta[i] = jog.read_array()
        frame = camera.wait_newer(time.monotonic(), cfg.frame_timeout_s)
        H = H_backdrop_camera if H_backdrop_camera is not None else find_backdrop(frame.image, layout)
        out.coverage[i] = shadow_coverage(rectify(frame.image, H, window_m, res))
        out.t[i], out.H_backdrop_camera = frame.t, H
        if keep_photos:
            out.photos.append(frame.image.copy())
        if on_capture is not None:
            on_capture(out.theta[i], out.coverage[i], frame.t)
        report(progress, "capture", i + 1, n)
        log.debug("captured pose %d/%d at frame %d", i + 1, n, frame.index)
    return out


def capture_walk(
    bus,
    calibration: Calibration,
    camera: Camera,
    n: int,
    folder: Path,
    cfg: CaptureConfig | None = None,
    step_rad: float = 0.25,
    seed: int = 0,
    layout: BackdropLayout | None = None,
    H_backdrop_camera: np.ndarray | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> CaptureSet:
    """Capture ``n`` (pose, shadow) pairs to learn from into the capture set ``folder`` (continued when it holds one
    for the same rig): a seeded collision-free random walk from the rest pose (each joint at most ``step_rad`` per
    pose, so each move is short), saved every 25 pairs as it goes (an interruption keeps what was captured). The
    set's rig is the one ``calibration`` records (its measured geometry and roll, at ``cfg.resolution``)."""
    cfg = cfg or CaptureConfig()
    hand = load_hand()
    with CollisionWorld(hand) as world:
        poses = walk_poses(hand, n, np.random.default_rng(seed), step_rad, hand.rest_pose(), world.in_collision)
    rig = calibration.rig().with_resolution(cfg.resolution)
    source = f"{n} poses of a random walk (step {step_rad:g} rad, seed {seed}) photographed by {camera.name}"
    with CaptureRecorder(folder, rig.to_dict(), hand.hash, source) as rec:
        capture_poses(bus, calibration, camera, poses, rig.window, cfg, layout, H_backdrop_camera, progress, cancel,
                      keep_photos=False, on_capture=lambda theta, cov, t: rec.append(theta, cov >= 0.5, t))  # fmt: skip
    return rec.captures


def open_camera_source(source: str | int, emulator=None, calibration=None, true_rig: str | Path | None = None,
                       fps: float = 30.0, hand=None) -> Camera:  # fmt: skip
    """The camera a face names (not yet open): a device index (``0`` or ``"0"``), a video file or frame folder, or
    ``"virtual"``: ``emulator``'s measured angles (through ``calibration``) rendered on the rig of the ``true_rig``
    file and photographed by its camera (:class:`~hardware.virtual_camera.VirtualCamera`). The one way every face
    opens a camera (``calibrate-rig``, ``capture``, ``play --camera``, the Rig and Export panels)."""
    if str(source).strip() != "virtual":
        if true_rig is not None:
            raise ValueError("a true rig file describes the virtual camera's world: use it with the virtual camera")
        return Camera(int(source) if str(source).strip().isdigit() else source)
    from hardware.virtual_camera import VirtualCamera, emulator_angles
    from studio.sim.photo import CameraModel
    from studio.sim.rig_file import read_rig_file

    if true_rig is None:
        raise ValueError("the virtual camera needs a true rig file (YAML): the rig as it really is, to photograph")
    if emulator is None or calibration is None:
        raise ValueError("the virtual camera photographs the servo emulator's hand: play on the emulator")
    rig, camera = read_rig_file(true_rig)
    angles = emulator_angles(emulator, calibration)
    return Camera(VirtualCamera(angles, rig, CameraModel.from_dict(camera), fps=fps, hand=hand))
