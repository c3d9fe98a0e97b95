"""The Rig panel driven without a browser, on the servo emulator and the virtual camera: the photograph shows the
window the markers (or four clicked corners) put on it and the window's shadow beside it, pixel for pixel; a missing
camera, a photograph without markers and a latched e-stop are one line each; a calibration runs to the end in the
background (a lower loss, the compare sheet, saved on the artist's click) or stops on Cancel with the servos stopped.
"""

from __future__ import annotations

import io
import math
import re
import threading
import time

import cv2
import numpy as np
import pytest
from PIL import Image
from studio.assets import asset

from hardware.calibration import load_calibration
from hardware.constants import CENTER_UNITS
from hardware.estop import set_latch
from hardware.jog import JogConfig
from studio.learn.rig_fit import RigFitConfig
from studio.project.capture import CaptureConfig
from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.project.rig_calibration import RigCalibrationConfig
from studio.sim.rig_file import read_rig_file
from studio.sim.shadow import ShadowRenderer
from studio.targets.backdrop import find_backdrop
from widgets.jog import JogPanel, JogPanelConfig
from widgets.rig import RigPanel, RigPanelConfig, rig_panel
from widgets.rig_view import CORNER_RGB, OUTLINE_RGB, window_in_photo
from widgets.state import StudioState

SMALL = RigPanelConfig(RigCalibrationConfig(poses=3, capture=CaptureConfig(resolution=128, settle_s=0.1),
                                            fit=RigFitConfig(max_evals=60)))  # fmt: skip
TRUE_RIG = "light_distance_m: 2.7\nmount_roll_deg: 3\nfoam_mm: 1.5\n"  # the rig as it really is


@pytest.fixture
def state(tmp_path):
    project = Project.create(tmp_path / "rig.shadow", sources=[asset("targets/asl_o.jpeg")])
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


@pytest.fixture
def panel(state, hand, tmp_path):
    (tmp_path / "rig.yaml").write_text(TRUE_RIG)
    p = RigPanel(state, SMALL, hand)
    p.source.value, p.true_rig.value = "virtual", str(tmp_path / "rig.yaml")
    yield p
    p.close()


def pixels(png: bytes) -> np.ndarray:
    """An Image widget's PNG as RGB ``(H, W, 3)`` uint8."""
    return np.array(Image.open(io.BytesIO(png)).convert("RGB"))


def shown_shadow(p: RigPanel) -> np.ndarray:
    """The rectified window beside the photograph: ``(S, S)`` bool, True where it is dark (shadow)."""
    return pixels(p.view.mask.value).mean(axis=2) < 128


def true_shadow(hand, p: RigPanel, theta: np.ndarray) -> np.ndarray:
    """The shadow the true rig casts of ``theta (21,)`` rad at the panel's mask size, ``(S, S)`` bool."""
    rig, _ = read_rig_file(p.true_rig.value)
    renderer = ShadowRenderer(hand, rig.with_resolution(p.cfg.mask_px))
    return renderer.render_one(np.clip(theta, hand.lower, hand.upper)) > 0


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return (a & b).sum() / max(1, (a | b).sum())


def losses(text: str) -> tuple[float, float]:
    before, after = re.search(r"loss ([0-9.]+) → ([0-9.]+)", text).groups()
    return float(before), float(after)


def test_show_camera_outlines_the_window_and_shows_its_shadow_then_clicked_corners_do_the_same(panel, hand):
    assert "Rig" in panel.widget.children[0].value and panel.true_rig.disabled is False
    release, grab = threading.Event(), panel._show_camera
    panel._show_camera = lambda: release.wait(30) and grab()  # held: the click must not wait for the camera
    try:
        panel.show_button.click()  # the frame is grabbed in the panel's thread, the buttons resting meanwhile
        assert panel.show_button.disabled and panel.calibrate_button.disabled and panel.showing.is_alive()
    finally:
        release.set()
    panel.showing.join(60)
    del panel._show_camera
    assert not panel.show_button.disabled and not panel.calibrate_button.disabled
    assert "backdrop found" in panel.messages.text, panel.messages.text
    photo = panel.view.photo
    shown = pixels(panel.view.picker.image.value)
    outline = np.all(shown == OUTLINE_RGB, axis=2)
    scale = shown.shape[1] / photo.shape[1]
    corners = window_in_photo(find_backdrop(photo), panel.view.window_m) * scale  # the window, screen px
    near = np.zeros_like(outline, np.uint8)
    cv2.polylines(near, [np.round(corners).astype(np.int32)], True, 1, 7)
    assert outline.sum() > 500 and (outline & (near > 0)).sum() > 0.95 * outline.sum()  # on the window's edges
    rest = load_calibration(None, hand).to_rad(np.full(21, float(CENTER_UNITS)))  # the emulator starts there
    truth = true_shadow(hand, panel, rest)
    assert truth.mean() > 0.05 and iou(shown_shadow(panel), truth) > 0.9  # dark where the true rig's shadow is
    # the fallback: the artist clicks the window's four corners (TL, TR, BR, BL as the audience sees them)
    panel.view.mode.value = "click"
    assert panel.view.picker.clicking and panel.view.H is None and panel.view.mask.value == b""
    for x, y in corners:
        panel.view.picker.click(x, y)
    assert "where you clicked" in panel.messages.text
    assert np.abs(window_in_photo(panel.view.H, panel.view.window_m) - corners / scale).max() < 2.0  # camera px
    assert np.all(pixels(panel.view.picker.image.value) == CORNER_RGB, axis=2).sum() > 100
    assert iou(shown_shadow(panel), truth) > 0.9


def test_the_jog_panels_emulator_is_photographed_in_its_pose(state, panel, hand):
    jog = JogPanel(state, config=JogPanelConfig(jog=JogConfig(speed_rad_s=20.0, min_move_s=0.0)), hand=hand)
    try:
        assert jog.connect()
        wrist = jog.cal.joint_names.index("wrist")
        jog.sliders[wrist].value = 40.0
        time.sleep(0.6)  # the servo gets there
        assert panel.show_camera(), panel.messages.text
        assert jog.session.is_open  # borrowed, not closed
        theta = jog.cal.to_rad(np.array([jog.emulator.positions()[i] for i in jog.cal.ids], float))
        assert theta[wrist] == pytest.approx(math.radians(40), abs=0.02)
        assert iou(shown_shadow(panel), true_shadow(hand, panel, theta)) > 0.9
    finally:
        jog.close()


def test_a_missing_camera_no_markers_and_a_latched_estop_are_one_line_each(panel, tmp_path, estop_file):
    panel.source.value = str(tmp_path / "nothing.mp4")
    assert not panel.show_camera()
    assert "video file not found" in panel.messages.text and "nothing.mp4" in panel.messages.text
    frames = tmp_path / "frames"
    frames.mkdir()
    cv2.imwrite(str(frames / "f0.png"), np.full((240, 320, 3), 200, np.uint8))  # a plain wall: no backdrop
    panel.source.value = str(frames)
    assert panel.show_camera()
    text = panel.messages.text
    assert "found 0 of the backdrop's 4 markers" in text and "click the window's four corners" in text, text
    assert panel.view.mode.value == "click" and panel.view.picker.clicking and panel.view.mask.value == b""
    assert not np.all(pixels(panel.view.picker.image.value) == OUTLINE_RGB, axis=2).any()
    assert not panel.calibrate() and "four corners" in panel.messages.text  # nothing clicked yet
    panel.source.value = ""
    assert not panel.show_camera() and "type the camera" in panel.messages.text
    panel.view.mode.value = "markers"  # chosen by the artist: it stays, and says why there is no window
    assert panel.view.mode.value == "markers" and "found 0 of the backdrop's 4 markers" in panel.messages.text
    panel.source.value = "virtual"
    set_latch("a test")
    assert panel.calibrate() and panel.wait(30)
    text = panel.messages.text
    assert "e-stop is latched" in text and "not opened" in text and "Traceback" not in text, text
    assert not panel.calibrate_button.disabled and panel.cancel_button.disabled and panel.result is None


@pytest.mark.slow  # a whole calibration on the virtual camera (10 s)
def test_calibrate_to_the_end_then_save_on_the_artists_click(panel, state, hand):
    assert rig_panel(state, SMALL).save() is None  # nothing to save yet: a message
    assert panel.save_button.disabled and panel.poses.value == 3
    assert panel.calibrate()
    assert panel.calibrate_button.disabled and panel.show_button.disabled and not panel.cancel_button.disabled
    assert not panel.calibrate()  # one at a time
    assert panel.wait(120), "the calibration did not end"
    before, after = losses(panel.summary.value)
    assert after < before and after < 0.05, (panel.summary.value, panel.messages.text)
    assert "now match the camera" in panel.messages.text and "mount roll" in panel.summary.value
    assert abs(panel.result.summary["mount_roll_deg"] - 3.0) < 0.5, panel.result.summary
    sheet = pixels(panel.compare.value)
    assert sheet.shape[0] > 3 * 100 and sheet.std() > 10  # three rows of pictures
    assert panel.progress.description == "done" and not panel.save_button.disabled and panel.cancel_button.disabled
    path = state.project.path / "calibration.yaml"
    assert not path.exists()  # never written before the click
    panel.save_button.click()
    saved = load_calibration(path, hand)
    assert "saved the measured rig" in panel.messages.text and state.extras["calibration_path"] == path
    assert math.degrees(saved.roll) == pytest.approx(panel.result.summary["mount_roll_deg"], abs=1e-4)
    assert saved.measured["foam_mm"] == panel.result.summary["foam_mm"]
    assert panel.save() == path and "replaced" in panel.messages.text
    assert RigPanel(state, SMALL, hand).cal.roll == pytest.approx(saved.roll)  # the next panel starts from it


def test_cancel_mid_run_stops_the_servos(panel):
    panel.poses.value = 12
    assert panel.calibrate()
    deadline = time.monotonic() + 30
    while "pose 1 of 12" not in panel.status.value and time.monotonic() < deadline:
        time.sleep(0.05)
    assert panel.cancel_button.disabled is False and panel.cancel()
    assert panel.wait(10), "cancel did not stop the calibration"
    text = panel.messages.text
    assert "calibration stopped: cancelled" in text and "servos stopped, torque held" in text, text
    assert panel.last_close.stopped and panel.result is None and panel.progress.description == "stopped"
    assert not panel.calibrate_button.disabled and panel.cancel_button.disabled and panel.save_button.disabled
