"""The Optimise panel (widgets.optimise) driven in Python on a real project and its real job queue: progress shown
as the job runs in the worker, a cancel within a second leaving the project as it was, a finished job's result
applied and its shadow shown, a "stale" run (run_project) reported."""

from __future__ import annotations

import time

import numpy as np
import pytest
from studio.assets import asset

from studio.imitate.config import RefineConfig, SearchConfig, SequenceConfig
from studio.jobs import JobState
from studio.jobs.events import JobEvent
from studio.project.jobs import queue_for
from studio.project.project import Project
from widgets.optimise import OptimiseConfig, mask_picture, optimise_panel
from widgets.state import StudioState

TINY = SequenceConfig(first=SearchConfig(batch=8, iterations=20), next=SearchConfig(batch=8, iterations=10, lr=0.08),
                      refine=RefineConfig(steps=20, restarts=1), candidates=1)  # fmt: skip
LONG = SequenceConfig(first=SearchConfig(batch=4, iterations=1_000_000, lr=0.08, log_every=1), candidates=1,
                      retrieve=True)  # fmt: skip


@pytest.fixture
def state(tmp_path):
    # the upright rig: these tests follow the keyframe jobs (roll auto's job: tests/test_pipeline.py, test_mount.py)
    project = Project.create(tmp_path / "still.shadow", sources=[asset("targets/asl_o.jpeg")], roll=0)
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


def snapshot(project: Project) -> tuple:
    files = {p.relative_to(project.path): p.read_bytes() for p in sorted(project.path.rglob("*")) if p.is_file()}
    return files, dict(project.results), project.history


def until(condition, timeout: float, poll=None) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if poll is not None:
            poll()
        if condition():
            return True
        time.sleep(0.05)
    return False


def started(panel, timeout: float = 30.0):
    """The one job ``panel.start`` made, once the run submitted it."""
    assert until(lambda: len(panel.jobs) > 0, timeout), panel.status.value
    (job,) = panel.jobs
    return job


@pytest.mark.slow
def test_progress_advances_and_a_cancel_within_a_second_leaves_the_project_unchanged(state):
    panel = optimise_panel(state, OptimiseConfig(sequence=LONG))
    try:
        assert "Optimise" in panel.widget.children[0].value
        before = snapshot(state.project)
        t0 = time.monotonic()
        panel.start("keyframe")
        assert time.monotonic() - t0 < 1.0  # the kernel is free: the job runs in the queue's worker
        assert panel.buttons["keyframe"].disabled and not panel.cancel_button.disabled
        job = started(panel)
        assert until(lambda: panel.step > 0 and any(b.value > 0 for b in panel.bars.values()), 90, panel.refresh)
        first = panel.step
        assert until(lambda: panel.step > first, 30, panel.refresh)  # it keeps advancing
        assert until(lambda: "search" in panel.bars, 90, panel.refresh)  # after the first answer and the sweep
        assert "sweep" in panel.bars and "best loss so far" in panel.loss.value
        t0 = time.monotonic()
        assert panel.cancel()
        assert job.wait(1.0) == JobState.CANCELLED and time.monotonic() - t0 < 1.0
        assert until(lambda: "cancelled" in panel.status.value, 5, panel.refresh)
        assert not panel.busy and not panel.buttons["keyframe"].disabled and panel.cancel_button.disabled
        assert snapshot(state.project) == before and not state.project.can_undo
        assert "cancelled" in panel.job_list.value
    finally:
        panel.close()


@pytest.mark.slow
def test_a_finished_job_applies_its_result_and_the_panel_shows_its_shadow(state):
    panel = optimise_panel(state, OptimiseConfig(sequence=TINY))
    heard = []
    state.on_change(heard.append)
    try:
        k = state.project.keyframes[0].id
        panel.start("keyframe")
        job = started(panel)
        assert job.wait(180) == JobState.DONE, job.error
        result = state.project.results[k]
        assert state.project.history[-1] == f"result of keyframe {k}" and state.project.pending_keyframes() == []
        # the panel's own writer thread draws it (no refresh() here): the result's shadow beside the target
        shown = lambda: panel.shown_shadow is not None and np.array_equal(panel.shown_shadow, result.shadow)  # noqa: E731
        assert until(lambda: shown() and not panel.busy, 10)
        assert panel.shadow_image.value == mask_picture(result.shadow, panel.cfg.image_px)
        assert panel.target_image.value == mask_picture(state.project.keyframe_masks(k)[0], panel.cfg.image_px)
        assert until(lambda: "project" in heard, 10)  # the other panels are told (after the draw, same thread)
        assert "done" in panel.job_list.value and "done" in panel.status.value
        state.undo()
        assert k not in state.project.results
    finally:
        panel.close()


@pytest.mark.slow
def test_all_stale_runs_the_project_and_reports(state):
    panel = optimise_panel(state, OptimiseConfig(sequence=TINY))
    try:
        panel.start("stale")
        assert until(lambda: panel.report is not None, 240)
        report = panel.report
        assert report.optimised == [state.project.keyframes[0].id], report.message
        assert until(lambda: report.message in panel.messages.text, 5)
        assert until(lambda: not panel.busy, 5)
        panel.start("stale")
        assert until(lambda: panel.report not in (None, report), 60)
        assert panel.report.optimised == [] and panel.report.skipped == report.optimised  # nothing recomputed
        with pytest.raises(ValueError, match="kind must be one of"):
            panel.start("bogus")
    finally:
        panel.close()


@pytest.mark.slow
def test_the_writer_redraws_on_its_own_at_most_ten_times_a_second(state):
    panel = optimise_panel(state, OptimiseConfig(sequence=LONG, redraw_hz=10.0))
    redraws = []
    panel.status.observe(lambda change: redraws.append(time.monotonic()), names="value")  # elapsed: new each draw
    try:
        panel.start("keyframe")
        job = started(panel)
        assert until(lambda: panel.step > 0, 90)  # no refresh() here: the panel's writer thread draws
        redraws.clear()
        time.sleep(2.0)
        assert 3 <= len(redraws) <= 2.0 * 10 + 2, len(redraws)
    finally:
        panel.close()
    assert job.wait(1.0) == JobState.CANCELLED  # closing the panel cancels what it started


@pytest.mark.slow
def test_the_whole_video_runs_the_sources_keyframes_in_order_one_job_each(tmp_path):
    from studio.targets.video import DEFAULT_VIDEO

    project = Project.create(tmp_path / "two.shadow", sources=[asset("targets/asl_o.jpeg"), DEFAULT_VIDEO], roll=0)
    state = StudioState(project, queue_for(project))
    panel = optimise_panel(state, OptimiseConfig(sequence=TINY))
    try:
        state.select(frame=len(project.frames) - 1)  # a frame of the horse
        video = [kf.id for kf in project.keyframes if project.frames[kf.representative].source == 1]
        panel.start("video")
        assert until(lambda: not panel.busy and panel.report is not None, 240, panel.refresh), panel.status.value
        assert panel.report.optimised == video, panel.report.message  # in first-appearance order (sequential)
        assert [panel.keyframes_of(j.id) for j in panel.jobs] == [[k] for k in video]
        assert all(j.state == JobState.DONE for j in panel.jobs)
        assert sorted(project.results) == sorted(video)  # the still's keyframe was not part of it
        last = panel.jobs[-1]
        assert until(lambda: "refine" in panel.bars, 10), list(panel.bars)  # the last job's stages, a bar each
        assert panel.keyframes_of(last.id) == [video[-1]]
    finally:
        panel.close()
        state.close()


def test_the_loss_shown_is_the_newest_stages_best_not_a_minimum_across_stages(state):
    """A search reports the self-model's loss and a later keyframe has another target: the panel shows each
    stage's own best, never a lower number left over from an earlier stage."""
    panel = optimise_panel(state, OptimiseConfig(sequence=TINY))

    def event(seq: int, stage: str, best: float) -> JobEvent:
        return JobEvent(job_id=7, kind="imitate-video", state=JobState.RUNNING, stage=stage, step=1, total=2,
                        best=best, shadow=None, elapsed=0.1 * seq, seq=seq)  # fmt: skip

    try:
        for i, (stage, best) in enumerate([("keyframe 1/2: refine", 0.12), ("keyframe 2/2: search", 0.31)]):
            panel._draw_event(event(i, stage, best))
        assert panel.best == 0.31 and "0.3100" in panel.loss.value and "keyframe 2/2: search" in panel.loss.value
        panel._draw_event(event(2, "keyframe 2/2: refine", float("nan")))  # a stage with no loss keeps the last one
        assert panel.best == 0.31 and set(panel.bars) == {"keyframe 1/2: refine", "keyframe 2/2: search",
                                                          "keyframe 2/2: refine"}  # fmt: skip
    finally:
        panel.close()
