"""The Review panel (widgets.review) driven in Python, offline: the recording written beside the project (and served
to the embedded Rerun viewer when rerun-notebook is installed, else a message saying how to get it and how to open
the file), target vs shadow of the frame in view following the selection and results, the meshcat scene redrawn
and its server stopped when the panel closes."""

from __future__ import annotations

import os
import sys

import ipywidgets as w
import numpy as np
import pytest

from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.review.blueprint import RENDERED, TARGET
from studio.review.readback import read_recording
from studio.targets.video import DEFAULT_VIDEO
from widgets.optimise import mask_picture
from widgets.review import ReviewConfig, notebook_viewer_missing, review_panel
from widgets.state import StudioState


@pytest.fixture
def state(tmp_path):
    project = Project.create(tmp_path / "horse.shadow", sources=[DEFAULT_VIDEO])
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return not open(f"/proc/{pid}/stat").read().split()[2] == "Z"


def test_review_panel_follows_the_selection_and_results_and_closes_its_scene(state, hand):
    p = state.project
    panel = review_panel(state)
    try:
        assert "Review" in panel.widget.children[0].value
        assert os.environ["RERUN_NOTEBOOK_ASSET"] == "inline"  # the viewer never fetches its JavaScript online
        assert panel.rrd == p.path.with_suffix(".rrd") and panel.rrd.exists()
        if notebook_viewer_missing() is None:  # rerun-notebook installed: the live viewer is embedded
            assert panel.viewer is not None and panel.viewer_box.children == (panel.viewer,)
            assert isinstance(panel.viewer, w.DOMWidget) and panel.viewer._url == panel.recording.server_url
        else:
            text = panel.viewer_box.children[0].value
            assert "pip install rerun-notebook" in text and f"rerun {panel.rrd}" in text
        assert panel.shown_frame == 0 and panel.shown_shadow is None and "no result yet" in panel.caption.value
        assert panel.target_image.value == mask_picture(p.state.targets[0], panel.cfg.image_px)
        assert np.allclose(panel.scene_pose, hand.rest_pose()) and "<iframe srcdoc=" in panel.scene_html.value
        first_html = panel.scene_html.value
        rows = read_recording(panel.rrd)[f"/{RENDERED}"]["rows"]  # flushed: readable while it is written

        last = len(p.frames) - 1
        state.select(frame=last)
        assert panel.shown_frame == last
        assert panel.target_image.value == mask_picture(p.state.targets[last], panel.cfg.image_px)

        k = p.keyframes[int(p.assignment()[last])].id
        pose = hand.rest_pose().copy()
        pose[hand.joint_names.index("index_pip")] = 0.9
        shadow = np.zeros((32, 32), np.uint8)
        shadow[8:24, 10:20] = 1
        state.edit("set_result", k, pose, {"total": 0.25, "base": 0.2}, shadow, inputs=p.keyframe_inputs(k))
        assert np.array_equal(panel.shown_shadow, shadow) and "loss 0.2500" in panel.caption.value
        assert panel.shadow_image.value == mask_picture(shadow, panel.cfg.image_px)
        assert np.allclose(panel.scene_pose, pose) and panel.scene_html.value != first_html
        assert np.array_equal(panel.scene.theta, pose)
        pid = panel.scene.server_pid
        assert pid is not None and alive(pid)
    finally:
        panel.close()
    assert panel.scene.closed and not alive(pid)  # the meshcat server is stopped with the panel
    assert panel.recording.closed
    recording = read_recording(panel.rrd)  # the file holds the project, re-logged after the result
    assert recording[f"/{RENDERED}"]["rows"] > rows and f"/{TARGET}" in recording  # the result's shadow was logged
    state.select(frame=0)  # a closed panel ignores later changes
    assert panel.shown_frame == last


def test_without_rerun_notebook_the_panel_says_how_to_get_it(state, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun_notebook", None)  # as if the package were not installed
    assert "pip install rerun-notebook" in notebook_viewer_missing()
    panel = review_panel(state, ReviewConfig(scene=False))
    try:
        assert panel.viewer is None and panel.scene is None and panel.scene_html.value == ""
        text = panel.viewer_box.children[0].value
        assert "pip install rerun-notebook" in text and f"rerun {panel.rrd}" in text
        assert panel.recording.server_url is None  # nothing served that no viewer would read
    finally:
        panel.close()
