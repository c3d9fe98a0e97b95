"""The Export tab's "play with camera" driven without a browser: a one-still project's planned show played on the
emulator while the virtual camera photographs a true rig that is not the nominal one; the rows it shows are
checked by their pixels, the loss table by its cells, and what cannot start says why in the artist's words."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from studio.assets import asset

from studio.jobs import JobState
from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.project.show_capture import ShowCaptureConfig
from studio.project.show_timing import ShowLayout
from studio.review.real_vs_sim import ONLY_REAL, ONLY_SIM
from studio.review.sheets import BACKDROP, SHADOW
from studio.sim.shadow import Rig, ShadowRenderer
from widgets.export import ExportConfig, ExportPanel
from widgets.real_vs_sim import RealVsSimConfig, RealVsSimView
from widgets.state import StudioState

TILE = 160
TRUE_RIG = "light_distance_m: 2.8\nmount_roll_deg: 2.0\ncamera: {width: 480, height: 360}\n"


@pytest.fixture
def state(tmp_path, hand):
    """A one-still project whose keyframe has a result (a bent index finger), its show planned (held 0.5 s)."""
    project = Project.create(tmp_path / "camera.shadow", sources=[asset("targets/asl_o.jpeg")], roll=0)
    pose = hand.rest_pose().copy()
    pose[hand.joint_names.index("index_pip")] = 0.8
    k = project.keyframes[0].id
    shadow = ShadowRenderer(hand, Rig(resolution=32)).render_one(pose)
    project.set_result(k, pose, {"total": 0.4}, shadow, inputs=project.keyframe_inputs(k))
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


def share(img: np.ndarray, rgb) -> float:
    return float((np.abs(img.astype(int) - rgb).max(-1) <= 3).mean())


def test_play_with_the_virtual_camera_shows_real_beside_simulated(state, tmp_path):
    panel = ExportPanel(state, ExportConfig(layout=ShowLayout(still_hold_s=0.5)))
    view = panel.real_vs_sim
    assert isinstance(view, RealVsSimView) and view.widget in panel.widget.children  # the Export tab holds it
    view.cfg = RealVsSimConfig(capture=ShowCaptureConfig(resolution=128))
    try:
        view.play_button.click()  # no show yet: said, nothing queued
        assert view.job is None and "plan show" in view.messages.text
        assert panel.plan().wait(60) == JobState.DONE
        view.play_button.click()
        assert view.job is None and "type the camera" in view.messages.text
        view.camera.value = "virtual"
        view.play_button.click()
        assert view.job is None and "needs a true rig file" in view.messages.text
        (tmp_path / "rig.yaml").write_text(TRUE_RIG)
        view.true_rig.value = str(tmp_path / "rig.yaml")
        panel.target.value = "port"
        view.play_button.click()
        assert view.job is None and "play on the emulator" in view.messages.text and "--" not in view.messages.text
        panel.target.value = "emulator"
        job = view.play()
        assert job is not None and not view.stop_button.disabled  # the notebook is free while it plays
        assert job.wait(60) == JobState.DONE, job.error
        assert view.result is not None and view.stop_button.disabled
        # the still's keyframe is reached at 0 s and held to 0.5 s: the show marks both
        assert "played" in view.messages.text and "the camera saw 2 of 2 keyframes" in view.messages.text
        assert [c.show_t for c in view.result.captures] == [0.0, 0.5]
        rows = view.table.value.split("<tr>")[2:]
        assert len(rows) == 2
        image = cv2.imdecode(np.frombuffer(view.image.value, np.uint8), cv2.IMREAD_COLOR)[..., ::-1]  # RGB
        assert image.shape == (2 * TILE + 6, 4 * TILE + 12, 3)
        for c, row in zip(view.result.captures, rows):
            assert 0.01 < c.losses["captured_vs_simulated"] < 0.25  # the true rig is near the nominal one, not it
            assert math.isfinite(c.losses["captured_vs_target"]) and math.isfinite(c.losses["simulated_vs_target"])
            cells = row.split("<td")  # keyframe, time, the three losses, no error
            assert f"k{c.index}" in cells[1] and f"{c.losses['captured_vs_simulated']:.3f}" in cells[5]
            # what the artist sees: target | captured | simulated | captured over simulated, by pixels
            y = c.index * (TILE + 6)
            target, captured, simulated, both = (image[y + 20 : y + TILE, i * (TILE + 4) : i * (TILE + 4) + TILE]
                                                 for i in range(4))  # fmt: skip
            for img in (target, captured, simulated):
                assert 0.02 < share(img, SHADOW) < 0.6 and share(img, SHADOW) + share(img, BACKDROP) > 0.97
            assert share(both, SHADOW) > 0.02 and share(both, ONLY_REAL) > 0.001 and share(both, ONLY_SIM) > 0.0005
    finally:
        panel.close()
