"""The Live panel driven without a browser, on the servo emulator (real pyserial over a pty), a frame folder made
here played as the camera, the real self-model with a small real retrieval index: the three pictures are checked by
their pixels (the camera's frame, the target dark where the test's silhouette is, the commanded shadow), Stop ends
the session with its thread joined and the servos stopped; a bad camera or port is one line and opens no servo; the
E-STOP latches (for every process), ends the session, refuses the next Start, and resets."""

from __future__ import annotations

import io
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from studio.assets import asset

from hardware.estop import is_latched
from hardware.playback_log import StopReason
from studio.imitate.retrieval import RetrievalConfig
from studio.project.jobs import queue_for
from studio.project.live_config import LiveConfig
from studio.project.project import Project
from studio.targets.images import TargetConfig, shadow_box, square_frame
from widgets.live import LivePanel, LivePanelConfig
from widgets.state import StudioState

SMALL_INDEX = RetrievalConfig(size=3000, chunk=1500, shortlist=48, seed=7)
FRAMES = 12
TILE = 200


def silhouette(k: int, size: tuple[int, int] = (240, 320)) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``k``: a BGR photograph ``(H, W, 3)`` of a dark hand-like silhouette (palm and three fingers, turning
    with ``k``) on an unevenly lit wall, and the silhouette itself ``(H, W)`` uint8, 1 = shadow."""
    h, w = size
    mask = np.zeros((h, w), np.uint8)
    cx, cy = w // 2, h // 2 + 30
    cv2.ellipse(mask, (cx, cy), (40, 55), 0, 0, 360, 1, -1)
    for f, base in enumerate((-30, 0, 30)):
        angle = np.radians(base + 10 * np.sin(k / 3 + f))
        tip = (int(cx + 110 * np.sin(angle)), int(cy - 50 - 110 * np.cos(angle)))
        cv2.line(mask, (cx + base // 2, cy - 40), tip, 1, 14)
    wall = np.linspace(200, 240, w, dtype=np.float32)[None, :].repeat(h, 0).astype(np.uint8)
    grey = np.where(mask > 0, 30, wall).astype(np.uint8)
    return np.dstack([grey] * 3), mask


def pixels(png: bytes) -> np.ndarray:
    """An Image widget's PNG as RGB ``(H, W, 3)`` uint8."""
    return np.array(Image.open(io.BytesIO(png)).convert("RGB"))


def dark(png: bytes) -> np.ndarray:
    """Where a picture is dark: ``(H, W)`` bool."""
    return pixels(png).mean(axis=2) < 128


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return (a & b).sum() / max(1, (a | b).sum())


def big(mask: np.ndarray, side: int) -> np.ndarray:
    return cv2.resize(np.asarray(mask, np.uint8), (side, side), interpolation=cv2.INTER_NEAREST) > 0


def wait_until(test, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not test() and time.monotonic() < deadline:
        time.sleep(0.05)
    return test()


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("live_camera")
    for k in range(FRAMES):
        cv2.imwrite(str(folder / f"{k:03d}.png"), silhouette(k)[0])
    return folder


@pytest.fixture(scope="module")
def panel(tmp_path_factory, hand):
    """One panel for the module: the self-model it loads on its first Start is kept for the next."""
    root = tmp_path_factory.mktemp("live_panel")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("SHADOW_STUDIO_CACHE", str(root / "cache"))  # the small index is built here, not in ~/.cache
        project = Project.create(root / "live.shadow", sources=[asset("targets/asl_o.jpeg")])
        state = StudioState(project, queue_for(project))
        cfg = LivePanelConfig(live=LiveConfig(max_seconds=30), retrieval=SMALL_INDEX, tile=TILE)
        p = LivePanel(state, cfg, hand)
        yield p
        p.close()
        state.close()


def test_live_shows_camera_target_and_shadow_then_stop_ends_it(panel, frames):
    assert "Live" in panel.widget.children[0].value and panel.source.value == "0"
    assert panel.servo_choice.value == "emulator" and panel.stop_button.disabled
    panel.source.value, panel.loop.value, panel.record.value = str(frames), True, True
    assert panel.start()
    assert not panel.start() and panel.start_button.disabled and not panel.stop_button.disabled  # one at a time
    assert wait_until(lambda: len(panel.view.drawn) == 3 and panel.view.draws >= 3, 60), panel.messages.text
    assert "live on the emulator" in panel.messages.text, panel.messages.text
    assert wait_until(lambda: "updates/s" in panel.view.status.value and "ms" in panel.view.status.value, 10)
    assert panel.stop() and panel.wait(10), "Stop did not end the session"
    assert not panel.running and not panel._thread.is_alive() and panel.live_session is None
    text = panel.messages.text
    assert "stopped: you pressed Stop" in text and "servos stopped, torque held" in text, text
    assert "Traceback" not in text and "\n" not in text
    assert panel.last_close.stopped and not panel.start_button.disabled and panel.stop_button.disabled
    result = panel.result
    assert result.playback.reason in (StopReason.COMPLETED, StopReason.CANCELLED) and result.updates >= 3
    assert [f.name for f in panel.files] == ["playback.npz", "live.rrd", "keyframes.json"]
    assert all(f.is_file() for f in panel.files) and str(panel.files[0].parent) in text

    # the pictures, as they stand after the last update (the drawer is joined: nothing changes them now)
    view = panel.view
    u = view.drawn["camera"]
    photo, truth = silhouette(u.frame_index % FRAMES)
    shown = pixels(view.pictures["camera"].value)
    assert shown.shape[1] == TILE and shown.std() > 20  # the camera's frame, not a blank
    want = cv2.resize(truth, (shown.shape[1], shown.shape[0]), interpolation=cv2.INTER_NEAREST) > 0
    assert iou(shown.mean(axis=2) < 100, want) > 0.9  # dark where the silhouette is
    u = view.drawn["target"]
    _, truth = silhouette(u.frame_index % FRAMES)
    target = dark(view.pictures["target"].value)
    assert target.shape == (TILE, TILE) and 0.05 < target.mean() < 0.7
    assert (target == big(u.target, TILE)).mean() > 0.99  # the update's target, black on white
    framed = square_frame(truth, u.target.shape[0], shadow_box(truth), TargetConfig.margin)
    assert iou(target, big(framed, TILE)) > 0.85  # where the test's silhouette is
    u = view.drawn["shadow"]
    shadow = dark(view.pictures["shadow"].value)
    assert 0.02 < shadow.mean() < 0.7 and (shadow == big(u.shadow, TILE)).mean() > 0.99
    assert not panel.stop()  # nothing runs


def test_a_bad_camera_or_port_is_one_line_and_opens_no_servos(panel, frames, tmp_path):
    panel.loop.value, panel.record.value = False, False
    panel.source.value = str(tmp_path / "nothing.mp4")
    assert panel.start() and panel.wait(20)
    text = panel.messages.text
    assert "video file not found" in text and "nothing.mp4" in text and "servos were not opened" in text, text
    assert "Traceback" not in text and "\n" not in text and panel.last_close is None and panel.result is None
    assert not panel.running and not panel.start_button.disabled
    panel.source.value = ""
    assert not panel.start() and "type the camera" in panel.messages.text
    panel.source.value = "virtual"
    assert not panel.start() and "virtual camera" in panel.messages.text
    panel.source.value, panel.servo_choice.value, panel.port.value = str(frames), "port", ""
    assert not panel.start() and "serial port" in panel.messages.text
    panel.port.value = str(tmp_path / "ttyNONE")
    assert panel.start() and panel.wait(60)
    text = panel.messages.text
    assert "could not run live" in text and "ttyNONE" in text and "Traceback" not in text, text
    assert panel.last_close is None and panel.result is None
    panel.servo_choice.value = "emulator"


def test_the_estop_latches_ends_the_session_and_refuses_the_next_start(panel, frames, estop_file):
    panel.source.value, panel.loop.value, panel.servo_choice.value = str(frames), True, "emulator"
    try:
        assert panel.start()
        assert wait_until(lambda: panel.live_session is not None and panel.view.offered >= 2, 60), panel.messages.text
        assert panel.estop() and estop_file.is_file() and is_latched()
        assert panel.wait(10), "the e-stop did not end the session"
        text = panel.messages.text
        assert text.count("E-STOP") == 1 and "latched" in text and "Traceback" not in text, text
        pb = panel.result.playback
        assert pb.reason == StopReason.ESTOP and pb.torque == "held" and panel.last_close.stopped
        assert panel.estop_button.description == "E-STOP LATCHED"
        assert panel.start() and panel.wait(20)  # latched: refused before any servo opens
        text = panel.messages.text
        assert "cannot start" in text and "e-stop is latched" in text and "servos were not opened" in text, text
        assert panel.reset() and not is_latched() and panel.estop_button.description == "E-STOP"
        assert panel.estop() and is_latched()  # with no session the E-STOP still latches, for every process
    finally:
        panel.reset()
    assert not is_latched()
