"""The Targets panel's work off the notebook's thread: every edit that reads the sources is a job on the project's
queue, the previews are drawn in the panel's own thread (the latest level last, the threshold alone before the
cleanup), and the interpreter exits cleanly while one is being drawn."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from targets_panel_support import STILL, finished, one_still_state  # the Targets panel tests' helpers

from studio.jobs import JobState
from widgets.targets import TargetsPanel


@pytest.fixture
def state(tmp_path):
    with one_still_state(tmp_path) as s:
        yield s


def test_a_late_draw_never_lands_over_a_newer_one(state, monkeypatch):
    """The slider's throttled draw runs on a timer thread: a draw still computing the old level when the slider moves
    must not land after the draw of the new level (the preview would show a level the slider no longer has)."""
    import widgets.targets as targets

    panel = TargetsPanel(state)
    inside, release = threading.Event(), threading.Event()
    real = targets.frame_preview

    def slow_at_five(grey, box, px, polarity, level, *rest, **kw):
        if level == 5.0:
            inside.set()
            release.wait(10.0)
        return real(grey, box, px, polarity, level, *rest, **kw)

    monkeypatch.setattr(targets, "frame_preview", slow_at_five)
    panel.threshold.value = 5.0
    old = threading.Thread(target=panel.refresh_preview)  # the timer's draw, caught mid-way
    old.start()
    assert inside.wait(10.0)
    panel.threshold.value = 200.0
    new = threading.Thread(target=panel.refresh_preview)
    new.start()
    new.join(0.5)  # without the panel's lock, the new draw lands now …
    release.set()  # … and the old one after it
    old.join(10.0)
    new.join(10.0)
    shown, png_shown, level = panel.preview_rgb.copy(), panel.preview.value, panel.preview_level
    panel.refresh_preview()  # a draw at 200 with nothing else running: the pixels the artist must be seeing
    assert np.array_equal(shown, panel.preview_rgb) and png_shown == panel.preview.value
    assert level == 200.0
    panel.threshold.value = 5.0
    panel.refresh_preview()
    assert not np.array_equal(shown, panel.preview_rgb)  # the old level's picture differs: the check can fail


def test_the_preview_is_throttled_but_ends_on_the_latest_value(state):
    panel = TargetsPanel(state)
    assert panel.drawer.settle()
    panel.threshold.value = 10.0
    assert panel.drawer.settle() and panel.preview_level == 10.0
    for level in (60.0, 70.0, 80.0, 90.0):  # faster than 15 a second: not each drawn, the last one surely
        panel.threshold.value = level
    assert panel.drawer.settle() and panel.preview_level == 90.0


def held(fn, inside: threading.Event, release: threading.Event):
    """``fn`` made slow: it says it has begun (``inside``), then waits for ``release`` before it runs."""

    def slow(*args, **kw):
        inside.set()
        release.wait(30.0)
        return fn(*args, **kw)

    return slow


def test_a_slow_preview_never_holds_the_notebook(state, monkeypatch):
    """A large photo's cleanup takes seconds: the slider's handler (the kernel's thread) only asks for a preview,
    and the drawing thread draws the latest level once the slow draw ends."""
    import widgets.targets as targets

    panel = TargetsPanel(state)
    assert panel.drawer.settle()
    inside, release = threading.Event(), threading.Event()
    monkeypatch.setattr(targets, "frame_preview", held(targets.frame_preview, inside, release))
    moved = threading.Thread(target=lambda: setattr(panel.threshold, "value", 40.0))
    moved.start()
    assert inside.wait(10.0)  # the draw has begun …
    moved.join(5.0)
    assert not moved.is_alive()  # … and the slider's handler has returned while it runs
    panel.threshold.value = 120.0  # asked for during the slow draw: drawn once it ends
    release.set()
    assert panel.drawer.settle() and panel.preview_level == 120.0


def test_an_edit_runs_as_a_job_the_notebook_never_waits_on_and_cancel_leaves_the_project_as_it_was(state):
    """Adding a source reads it (seconds on a long video): the click returns at once, the panel's line follows the
    job, its edit buttons rest until it ends (a second edit is refused in words, never decided on a project that the
    first is about to change), and Cancel stops it with nothing changed."""
    from studio.jobs import Job

    panel = TargetsPanel(state)
    gate = threading.Event()
    state.queue.submit(Job("hold", lambda report, cancel: gate.wait(30)))  # a run ahead of it on the queue
    panel.sample.value = "muybridge_horse.gif"
    panel.add_sample.click()
    assert len(state.project.sources) == 1  # the click returned with the source unread: it waits on the queue
    assert panel.job_info.value == "add muybridge_horse.gif: queued behind 1 job (the Optimise tab's list)"
    assert panel.add_sample.disabled and panel.apply_threshold.disabled and panel.upload.disabled
    assert not panel.cancel_job.disabled
    panel.threshold.value = 100.0
    panel.apply_threshold.click()  # as a script would: the browser does not send a resting button's click
    assert "has not ended yet" in panel.messages.text and state.project.state.still.threshold != 100.0
    gate.set()
    finished(panel)
    assert [s.kind for s in state.project.sources] == ["still", "video"] and state.selection.frame == 1
    assert not panel.add_sample.disabled and panel.cancel_job.disabled and panel.job_info.value.endswith("done")
    gate.clear()
    state.queue.submit(Job("hold", lambda report, cancel: gate.wait(30)))
    history = list(state.project.history)
    panel.hz.value = 1.0
    panel.apply_hz.click()
    panel.cancel_job.click()
    assert panel.job.wait(5) == JobState.CANCELLED
    gate.set()
    assert state.queue.wait(30) and list(state.project.history) == history and state.project.state.video.hz == 2.0
    assert not panel.apply_hz.disabled and panel.job_info.value.endswith("cancelled")


def test_the_interpreter_exits_cleanly_while_a_preview_is_being_drawn(tmp_path):
    """A daemon thread stopped at exit inside OpenCV aborts the process ("terminate called without an active
    exception"): the studio's background threads are waited for at exit instead. Here the script ends while the
    preview's thread is busy in OpenCV (a large photo's cleanup, made long and certain)."""
    import subprocess
    import sys

    script = f"""
import threading, time
import cv2, numpy as np
import widgets.targets as targets
from studio.project.jobs import queue_for
from studio.project.project import Project
from widgets.state import StudioState
busy, real = threading.Event(), targets.frame_preview
def slow(*args, **kw):
    big = np.zeros((2000, 2000), np.float32)
    busy.set()
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        cv2.GaussianBlur(big, (0, 0), 9.0)
    return real(*args, **kw)
targets.frame_preview = slow
project = Project.create({str(tmp_path / "b.shadow")!r}, [{str(STILL)!r}], roll=0)
panel = targets.TargetsPanel(StudioState(project, queue_for(project)))
assert busy.wait(30)
print("leaving while it draws", flush=True)
"""
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert out.returncode == 0 and "leaving while it draws" in out.stdout, out.stderr[-2000:]
    assert "terminate called" not in out.stderr


def test_the_threshold_alone_lands_before_a_slow_cleanup(state, monkeypatch):
    """On a large photo the stored picture (the project's whole cleanup) takes seconds: the threshold alone is shown
    at the new level first, the stored picture says it is being cleaned up, then lands."""
    import widgets.target_preview as target_preview

    panel = TargetsPanel(state)
    assert panel.drawer.settle()
    stored_before = panel.stored.value
    inside, release = threading.Event(), threading.Event()
    monkeypatch.setattr(target_preview, "mask_from_grey", held(target_preview.mask_from_grey, inside, release))
    panel.threshold.value = 150.0
    assert inside.wait(10.0)  # the cleanup has begun, and the left picture is already the new level's
    assert panel.preview_level == 150.0 and "cleaning up at level 150" in panel.stored_info.value
    assert panel.stored.value == stored_before
    release.set()
    assert panel.drawer.settle() and panel.stored.value != stored_before and "cleaning" not in panel.stored_info.value
