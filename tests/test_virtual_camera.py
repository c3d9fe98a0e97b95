"""hardware.virtual_camera: the true rig's shadow photographed behind VideoCapture's interface, read by Camera, and
read back into the shadow by the footage stage (the real rig's loop without a rig)."""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
import pytest

from hardware.calibration import default_calibration
from hardware.camera import Camera
from hardware.errors import ServoTimeout
from hardware.virtual_camera import VirtualCamera, emulator_angles
from studio.sim.backdrop import BackdropLayout
from studio.sim.hand import load_hand
from studio.sim.photo import CameraModel
from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer, iou
from studio.targets.backdrop import shadow_mask

HAND = load_hand()
SMALL = CameraModel(width=480, height=360, fov_deg=50.0, position_m=(0.1, 0.05, -2.0))  # a quick camera
POSES, _ = sample_poses(HAND, 2, np.random.default_rng(3))


def test_it_reads_like_a_videocapture_paced_to_its_rate():
    cam = VirtualCamera(lambda: HAND.rest_pose(), camera=SMALL, fps=20.0, hand=HAND)
    assert cam.isOpened()
    assert cam.get(cv2.CAP_PROP_FPS) == 20.0
    assert (cam.get(cv2.CAP_PROP_FRAME_WIDTH), cam.get(cv2.CAP_PROP_FRAME_HEIGHT)) == (480, 360)
    assert cam.get(cv2.CAP_PROP_BRIGHTNESS) == 0.0
    ok, first = cam.read()
    assert ok and first.shape == (360, 480, 3) and first.dtype == np.uint8
    t = time.monotonic()
    images = [cam.read()[1] for _ in range(4)]
    assert time.monotonic() - t >= 3 / 20.0 * 0.9  # four frames at least 1 / 20 s apart
    assert not np.array_equal(images[0], images[1])  # the noise changes from frame to frame
    assert cam.renderer.rig.resolution >= 512
    cam.release()
    assert not cam.isOpened() and cam.read() == (False, None)


@pytest.mark.parametrize("roll", [0.0, 0.7])
def test_the_footage_stage_reads_back_the_true_shadow(roll):
    rig = Rig(roll=roll)
    truth = ShadowRenderer(HAND, rig).render(POSES)  # 256², the rig's own resolution
    pose = {"k": 0}
    virtual = VirtualCamera(lambda: POSES[pose["k"]], rig=rig, hand=HAND)  # the default camera, behind the backdrop
    with Camera(virtual) as cam:
        assert cam.fps == 30.0
        first = cam.latest()
        mask = shadow_mask(first.image, BackdropLayout(), rig.window, rig.resolution)
        assert iou(mask, truth[0]) >= 0.97
        pose["k"] = 1  # the hand moves; a frame captured after that moment shows the new pose
        moved = time.monotonic()
        later = cam.wait_newer(moved, timeout_s=3.0)
        assert later.t > moved and later.index > first.index
        later = cam.wait_newer(later, timeout_s=3.0)  # the one read in flight may have sampled the old pose
        mask = shadow_mask(later.image, BackdropLayout(), rig.window, rig.resolution)
        assert iou(mask, truth[1]) >= 0.97


def test_angles_past_the_limits_are_clipped_not_refused():
    theta = HAND.upper + 0.01
    ok, image = VirtualCamera(lambda: theta, camera=SMALL, hand=HAND).read()
    assert ok and image.shape == (360, 480, 3)


def test_emulator_angles_turn_measured_servo_units_into_joint_angles():
    from hardware.emulator import ServoEmulator

    cal = default_calibration(HAND)
    want = np.clip(POSES[0], cal.lower, cal.upper)
    units = dict(zip(cal.ids, np.round(cal.to_units(want)).astype(int).tolist()))
    with ServoEmulator(cal.ids, positions=units) as emu:
        angles = emulator_angles(emu, cal)
        got = angles()
        assert got.shape == (21,)
        assert np.allclose(got, cal.to_rad(np.array([units[i] for i in cal.ids])))
        assert np.abs(got - want).max() < 0.5 * np.radians(0.24) + 1e-9  # within half a servo unit

    class Partial:  # a bus on which servo 21 is missing
        def positions(self) -> dict[int, float]:
            return {i: 500.0 for i in cal.ids[:-1]}

    with pytest.raises(ServoTimeout, match=f"servo {cal.ids[-1]} is not on the emulated bus"):
        emulator_angles(Partial(), cal)()


def test_a_camera_on_the_virtual_camera_closes_cleanly():
    virtual = VirtualCamera(lambda: HAND.rest_pose(), camera=SMALL, fps=60.0, hand=HAND)
    cam = Camera(virtual).open()
    cam.wait_newer(1, timeout_s=3.0)
    cam.close()
    assert not virtual.isOpened()
    assert not any(t.name.startswith("camera-reader") and t.is_alive() for t in threading.enumerate())
