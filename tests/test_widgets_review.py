"""The Review panel (widgets.review) driven in Python, offline: the recording written beside the project (and served
to the embedded Rerun viewer when rerun-notebook is installed, else a message saying how to get it and how to open
the file), target vs shadow of the frame in view following the selection and results, the meshcat scene redrawn
and its server stopped when the panel closes."""

from __future__ import annotations

import os
import sys
import threading
import time
from types import SimpleNamespace

import ipywidgets as w
import numpy as np
import pytest

from studio.jobs.events import JobState
from studio.jobs.job import Job
from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.review.blueprint import LOSS_TAB, RENDERED, SELF_MODEL, SERVO_TAB, TARGET
from studio.review.readback import read_recording
from studio.review.scene import ShadowScene
from studio.targets.video import DEFAULT_VIDEO
from widgets.images import mask_picture
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
        assert panel.opened.wait(60)
        assert "Review" in panel.widget.children[0].value
        assert os.environ["RERUN_NOTEBOOK_ASSET"] == "inline"  # the viewer never fetches its JavaScript online
        assert panel.rrd == p.path.with_suffix(".rrd") and panel.rrd.exists()
        if notebook_viewer_missing() is None:  # rerun-notebook installed: the live viewer is embedded
            box = panel.viewer_controls
            assert panel.viewer_box.children == (box.widget,) and box.viewer is panel.viewer
            assert isinstance(panel.viewer, w.DOMWidget) and panel.viewer._url == panel.recording.server_url
            assert (panel.viewer._width, panel.viewer._height) == ("auto", panel.cfg.viewer_height)  # 100 % wide
        else:
            text = panel.viewer_box.children[0].value
            assert "pip install rerun-notebook" in text and f"rerun {panel.rrd}" in text
        assert panel.shown_frame == 0 and panel.shown_shadow is None and "no result yet" in panel.caption.value
        assert panel.target_image.value == mask_picture(p.state.targets[0], panel.cfg.image_px)
        assert np.allclose(panel.scene_pose, hand.rest_pose()) and "MeshCat" in panel.scene_view.page
        first_html = panel.scene_view.page
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
        assert np.allclose(panel.scene_pose, pose) and panel.scene_view.page != first_html
        assert np.array_equal(panel.scene.theta, pose)
        pid = panel.scene.server_pid
        assert pid is not None and alive(pid)
    finally:
        panel.close()
    assert panel.scene.closed and not alive(pid)  # the meshcat server is stopped with the panel
    assert panel.recording.closed
    recording = read_recording(panel.rrd)  # the file holds the project, re-logged after the result
    assert recording[f"/{RENDERED}"]["rows"] > rows and f"/{TARGET}" in recording  # the result's shadow was logged
    # and the self-model's shadow of its pose, which the viewer's self-model view shows beside the rendered one
    predicted = [b for b in recording[f"/{SELF_MODEL}"]["batches"] if "Image:buffer" in b.schema.names]
    assert predicted and any(v is not None for b in predicted for v in b.column("Image:buffer").to_pylist())
    state.select(frame=0)  # a closed panel ignores later changes
    assert panel.shown_frame == last


def test_the_panel_opens_at_once_and_its_viewer_follows_when_ready(state, monkeypatch):
    """The recording and its viewer take seconds to open (the self-model's and the viewer's code load): the panel is
    built without waiting for them, says it is opening, follows the selection meanwhile, and an edit made while the
    project is first logged is in the recording once it is open."""
    from studio.review.recording import ProjectRecording

    release, logged = threading.Event(), []
    real = ProjectRecording.log_project

    def slow_first(self, project, model=None):
        logged.append(project.state)
        if len(logged) == 1:
            release.wait(30)
        return real(self, project, model)

    monkeypatch.setattr(ProjectRecording, "log_project", slow_first)
    built = []
    maker = threading.Thread(target=lambda: built.append(review_panel(state, ReviewConfig(scene=False))))
    maker.start()
    maker.join(20)
    assert built, "the panel waited for its recording"
    panel = built[0]
    try:
        assert "opening the Rerun viewer" in panel.viewer_box.children[0].value
        state.select(frame=2)
        assert panel.shown_frame == 2  # the panel works meanwhile
        deadline = time.monotonic() + 30
        while not logged and time.monotonic() < deadline:
            time.sleep(0.05)
        assert logged and not panel.opened.is_set() and panel.recording is None
        state.edit("set_keyframe_time", state.project.keyframes[0].id, 0.5)  # an edit while it is logged
        release.set()
        assert panel.opened.wait(60) and panel.recording is not None
        assert len(logged) == 2 and logged[-1] is state.project.state  # logged again: the project as it is now
    finally:
        release.set()
        panel.close()


def test_an_edit_undone_while_the_recording_opens_is_logged_as_the_project_is_now(state, monkeypatch):
    """An edit made while the project is first logged, and undone before the recording is published (the browser
    test's painted stroke and its Undo, on a busy machine): the first log read the edited project, and the undo
    brings back the very state object the panel noted before it, so the recording is logged again all the same;
    otherwise it would keep the edited project (a stale show: no frame on ``show_time``) until the next edit."""
    from studio.review.recording import ProjectRecording

    entered, release, first_done, undone = threading.Event(), threading.Event(), threading.Event(), threading.Event()
    real, logged = ProjectRecording.log_project, []

    def slow_first(self, project, model=None):
        first = not logged
        if first:
            entered.set()
            release.wait(30)
        logged.append(project.state)
        out = real(self, project, model)
        if first:
            first_done.set()
            undone.wait(30)
        return out

    monkeypatch.setattr(ProjectRecording, "log_project", slow_first)
    before = state.project.state
    panel = review_panel(state, ReviewConfig(scene=False))
    try:
        assert entered.wait(60)  # the panel noted the project's state and started to log it
        state.edit("set_keyframe_time", state.project.keyframes[0].id, 0.5)  # while the first log waits
        release.set()
        assert first_done.wait(30) and logged == [state.project.state]  # it logged the edited project
        assert state.undo() and state.project.state is before  # the state object it noted before logging
        assert panel.relogger.settle(10)  # the edits' own relogs came and went: no recording to log to yet
        undone.set()
        assert panel.opened.wait(60) and panel.recording is not None
        deadline = time.monotonic() + 10
        while len(logged) < 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(logged) >= 2 and logged[-1] is before  # logged again: the project as it is now
    finally:
        release.set()
        undone.set()
        panel.close()


def test_the_rig_scene_opens_in_the_background_and_draws_the_frame_in_view(state, hand, monkeypatch):
    """The meshcat scene's server takes a second or two to start: the panel is built without it, says so, and once
    the scene is up it shows the pose of the frame selected meanwhile; a panel closed while its scene starts stops
    that scene's server as soon as it is up."""
    import widgets.review_rig as review

    release, made = threading.Event(), []

    def held_scene(*args, **kwargs):
        release.wait(30)
        made.append(ShadowScene(*args, **kwargs))
        return made[-1]

    def built_aside():  # the panel built in another thread, or None if that waited 20 s
        built = []
        maker = threading.Thread(target=lambda: built.append(review_panel(state, ReviewConfig(viewer=False))))
        maker.start()
        maker.join(20)
        return built[0] if built else None

    monkeypatch.setattr(review, "ShadowScene", held_scene)
    for close_early in (False, True):
        release.clear()
        panel = built_aside()
        assert panel is not None, "the panel waited for its scene"
        try:
            assert panel.scene is None and panel.scene_view.page == "" and "starting" in panel.rig_heading.value
            if close_early:
                panel.close()
            else:  # meanwhile the artist selects frame 2, whose keyframe gets a result
                p = state.project
                k = p.keyframes[int(p.assignment()[2])].id
                pose = hand.rest_pose().copy()
                pose[hand.joint_names.index("index_pip")] = 0.9
                shadow = np.ones((8, 8), np.uint8)
                state.edit("set_result", k, pose, {"total": 0.25}, shadow, inputs=p.keyframe_inputs(k))
                state.select(frame=2)
            release.set()
            assert panel.opened.wait(60)
            if close_early:
                assert made[-1].closed and panel.scene is None  # its server was stopped as soon as it was up
                continue
            assert panel.scene is made[-1] and "starting" not in panel.rig_heading.value
            assert np.allclose(panel.scene_pose, pose) and np.array_equal(panel.scene.theta, pose)
            assert "MeshCat" in panel.scene_view.page and panel.shown_frame == 2
        finally:
            release.set()
            panel.close()


def test_without_rerun_notebook_the_panel_says_how_to_get_it(state, monkeypatch):
    monkeypatch.setitem(sys.modules, "rerun_notebook", None)  # as if the package were not installed
    assert "pip install rerun-notebook" in notebook_viewer_missing()
    panel = review_panel(state, ReviewConfig(scene=False))
    try:
        assert panel.opened.wait(60)
        assert panel.viewer is None and panel.scene is None and panel.scene_view.page == ""
        text = panel.viewer_box.children[0].value
        assert "pip install rerun-notebook" in text and f"rerun {panel.rrd}" in text
        assert panel.recording.server_url is None  # nothing served that no viewer would read
    finally:
        panel.close()


def test_the_viewer_follows_the_studio(state, hand):
    """The selection moves the viewer to that frame, a running optimisation to its newest step, a finished play's
    angles are logged and played, the show player moves the viewer and the meshcat scene to its time; the height
    control resizes the viewer, and with follow off nothing moves it."""
    if notebook_viewer_missing() is not None:
        pytest.skip("the notebook viewer needs the rerun-notebook package")
    panel = review_panel(state, ReviewConfig(follow_interval_s=0.0))
    assert panel.opened.wait(60)
    box, q = panel.viewer_controls, state.queue
    try:
        box.height.value = 800
        assert panel.viewer._height == 800
        state.select(frame=2)
        assert box.where == ("frame", 2.0)
        box.follow.value = False
        state.select(frame=3)
        assert box.where == ("frame", 2.0)  # not following: the viewer stays where the artist put it
        box.follow.value = True

        def optimise(report, cancel):
            for i in range(1, 5):
                report("search", i, 4, 1.0 / i, None)

        assert q.run(Job("imitate-keyframe", optimise), timeout=60).state == JobState.DONE
        assert box.where[0] == "opt_step" and box.where[1] >= 4  # where it last drew its best loss

        names = list(hand.joint_names)
        t = np.arange(12) / 40
        played = SimpleNamespace(joint_names=names, t=t, sent=np.zeros((12, len(names))), ramp_ticks=4,
                                 measured_t=t[::2], measured_joint=np.zeros(6, int), measured_rad=np.zeros(6),
                                 reason=SimpleNamespace(value="completed"), message="played")  # fmt: skip
        assert q.run(Job("play", lambda report, cancel: played), timeout=60).state == JobState.DONE
        # its commanded vs measured angles, played on show_time from the start of its ramp (4 ticks at 40 Hz), the
        # servo plot in front; a frame chosen then brings the loss plot back
        assert box.where == ("show_time", pytest.approx(-0.1))
        assert panel.recording.plot_in_front == SERVO_TAB
        state.select(frame=1)
        assert box.where == ("frame", 1.0) and panel.recording.plot_in_front == LOSS_TAB

        q.wait(timeout=300)  # the show preview the player plays is rendered
        shown = panel.preview.preview
        assert shown is not None and len(shown.clock.times) > 3
        panel.preview.player.index = 3
        clock = shown.clock
        expect = ("show_time", float(clock.times[3])) if clock.planned else ("frame", float(clock.frame[3]))
        assert box.where[0] == expect[0] and box.where[1] == pytest.approx(expect[1])
        if np.isfinite(clock.theta[3]).all():
            np.testing.assert_allclose(panel.scene_pose, clock.theta[3])
    finally:
        panel.close()
    recording = read_recording(panel.rrd)
    commanded = [e for e in recording if e.startswith("/servo/") and e.endswith("/commanded")]
    assert len(commanded) == len(names) and "/servo/wrist/measured" in recording  # the play's angles
    assert any(e.startswith("/loss/job") for e in recording)  # the optimisation's best loss on opt_step


def test_an_edit_never_waits_for_the_recording(state, monkeypatch):
    """The project is logged again after an edit in the panel's thread (a long video's project takes a tenth of a
    second or more): with that logging held, the edit returns at once; the edit is then logged, and closing the
    panel waits for it."""
    from studio.review.recording import ProjectRecording

    panel = review_panel(state, ReviewConfig(scene=False, viewer=False))
    release, held, logged = threading.Event(), threading.Event(), []
    try:
        assert panel.opened.wait(60)
        real = ProjectRecording.log_project

        def slow(self, project, model=None):
            held.set()
            release.wait(30)
            logged.append(project.state)
            return real(self, project, model)

        monkeypatch.setattr(ProjectRecording, "log_project", slow)
        k = state.project.keyframes[0].id
        edit = threading.Thread(target=state.edit, args=("set_hold", k, True))
        edit.start()
        assert held.wait(10)  # the logging has started, in the panel's thread
        edit.join(10)
        assert not edit.is_alive(), "the edit waited for the recording"
    finally:
        release.set()
        panel.close()
    assert logged and logged[-1].keyframe(k).hold  # the edit is in the recording
