"""The Optimise panel (widgets.optimise) driven in Python on a real project and its real job queue: progress shown
as the job runs in the worker, a cancel within a second leaving the project as it was, a finished job's result
applied and its shadow shown, a "stale" run (run_project) reported."""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import numpy as np
import pytest
from studio.assets import asset

from studio.imitate.config import PRESETS, STUDIO, JointConfig, RefineConfig, SearchConfig, SequenceConfig
from studio.imitate.index_cache import WAITING
from studio.jobs import Job, JobState
from studio.jobs.events import JobEvent
from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.project.run_report import RunReport
from widgets.images import mask_picture
from widgets.optimise import OptimiseConfig, optimise_panel
from widgets.optimise_view import budget_list, job_name
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
        other = state.queue.submit(Job("add-source", lambda report, cancel: None, title="add o.jpeg"))  # meanwhile
        assert panel._mine(job.id) and not panel._mine(other.id)  # another panel's job is never drawn as the run's
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
def test_the_whole_video_runs_the_sources_keyframes_in_order_one_job_each_then_together(tmp_path):
    from studio.targets.video import DEFAULT_VIDEO

    project = Project.create(tmp_path / "two.shadow", sources=[asset("targets/asl_o.jpeg"), DEFAULT_VIDEO], roll=0)
    state = StudioState(project, queue_for(project))
    together = replace(TINY, joint=JointConfig(generations=10, popsize=6, both_orders=True))
    panel = optimise_panel(state, OptimiseConfig(sequence=together))
    try:
        state.select(frame=len(project.frames) - 1)  # a frame of the horse
        video = [kf.id for kf in project.keyframes if project.frames[kf.representative].source == 1]
        assert len(video) >= 2
        panel.start("video")
        assert until(lambda: not panel.busy and panel.report is not None, 240, panel.refresh), panel.status.value
        assert panel.report.optimised == video, panel.report.message  # in first-appearance order (sequential)
        # one job a keyframe, then the source's keyframes refined together (studio.project.run_together)
        assert [panel.keyframes_of(j.id) for j in panel.jobs] == [[k] for k in video] + [video]
        assert all(j.state == JobState.DONE for j in panel.jobs)
        assert sorted(project.results) == sorted(video)  # the still's keyframe was not part of it
        last = panel.jobs[-1]
        assert panel.job_line(last.id) == f"keyframes {video[0]}–{video[-1]} together"

        def together_done() -> bool:  # the last job's bar, complete: its final event may come just after the run
            return "together" in panel.bars and panel.bars["together"].description.endswith(": done")

        assert until(together_done, 10, panel.refresh), {k: b.description for k, b in panel.bars.items()}
        assert panel.bars["together"].description == "keyframes together: done"
        again = [b for b in panel.bars if b.startswith("last to first: keyframe ")]  # posed in the other order first
        assert f"last to first: keyframe {video[-1]} ({len(video)} of {len(video)}): search" in again  # by its id
        assert again and all(panel.bars[b].value == 1.0 for b in again), list(panel.bars)
        assert last.shadow is not None and last.shadow.any()  # live shadows while they were posed again
    finally:
        panel.close()
        state.close()


def test_the_loss_shown_is_the_newest_stages_best_not_a_minimum_across_stages(state):
    """A search reports the self-model's loss and a later keyframe has another target: the panel shows each
    stage's own best, never a lower number left over from an earlier stage."""
    panel = optimise_panel(state, OptimiseConfig(sequence=TINY))

    def event(seq: int, stage: str, best: float) -> JobEvent:
        return JobEvent(job_id=7, kind="imitate-keyframes", state=JobState.RUNNING, stage=stage, step=1, total=2,
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


def keyframe_job(job_id: int, k: int, n: int, of: int):
    """A keyframe job of a run as ``project.run`` makes it: its keyframe and its place in the run on ``meta``."""
    job = Job("imitate-keyframes", lambda report, cancel: None, title=f"keyframe {k}", meta={"keyframes": [k],
              "of": (n, of)})  # fmt: skip
    job.id = job_id
    return job


def test_overall_progress_names_the_keyframe_of_the_run_and_bars_complete_when_a_job_is_done(state):
    panel = optimise_panel(state, OptimiseConfig(sequence=TINY, warm_index=False))

    def event(job_id, stage, step, total, done=False):
        now = JobState.DONE if done else JobState.RUNNING
        return JobEvent(job_id=job_id, kind="imitate-keyframes", state=now, stage=stage, step=step, total=total,
                        best=float("nan"), shadow=None, elapsed=1.0, seq=step)  # fmt: skip

    try:
        panel.jobs = [keyframe_job(11, 7, 3, 5)]
        panel._draw_event(event(11, "index", 16_384, 200_000))
        assert "keyframe 7 (3 of 5)" in panel.status.value
        assert "building the retrieval index of 200,000 poses (first use only, cached)" in panel.status.value
        assert "index 16384" not in panel.status.value and "1/1" not in panel.status.value
        waiting = JobEvent(11, "imitate-keyframes", JobState.RUNNING, "index", 0, 200_000, float("nan"), None, 1.0, 2,
                           item=WAITING)  # another process builds it: this job waits, and says so  # fmt: skip
        panel._draw_event(waiting)
        assert "(first use only, cached): waiting for another process or job building it" in panel.status.value
        panel._draw_event(event(11, "search", 30, 60))  # half-way when the search stops early
        assert panel.overall.value == pytest.approx(2 / 5) and "2 of 5 keyframes done" in panel.overall.description
        assert panel.bars["search"].value == 0.5
        panel._draw_event(event(11, "search", 30, 60, done=True))
        assert all(bar.value == 1.0 for bar in panel.bars.values())  # done is 100 %, whatever was reported last
        assert all(bar.description.endswith("done") for bar in panel.bars.values())
        assert panel.overall.value == pytest.approx(3 / 5) and "3 of 5 keyframes done" in panel.overall.description
        plan = Job("plan", lambda report, cancel: None, title="show")
        plan.id = 12
        panel.jobs.append(plan)
        for step in (1, 2):
            panel._draw_event(JobEvent(12, "plan", JobState.RUNNING, "timing", step, 4, float("nan"), None, 1.0, step))
        assert panel.bars["timing"].value == 0.5 and "the show" in panel.status.value
        panel._draw_event(JobEvent(12, "plan", JobState.DONE, "timing", 2, 4, float("nan"), None, 1.0, 3))
        assert panel.bars["timing"].value == 1.0
    finally:
        panel.close()


def test_all_stale_uses_the_allow_late_box_and_too_fast_says_what_to_tick(state, monkeypatch):
    panel = optimise_panel(state, OptimiseConfig(sequence=TINY, warm_index=False))
    seen = []

    def run(cfg, **kwargs):
        seen.append(cfg)
        late = [{"from_frame": 2, "to_frame": 3, "from_keyframe": 1, "to_keyframe": 4, "t_start": 0.7999999999999999,
                 "t_end": 1.05, "given_s": 0.25, "needed_s": 0.6180339}]  # fmt: skip
        return RunReport(str(state.project.path), too_fast=True, late=late,
                         message="no show: 1 transition too fast for the servos at the show's clock")  # fmt: skip

    monkeypatch.setattr(state.project, "run", run)
    try:
        assert "allow late transitions" in panel.allow_late.description and not panel.allow_late.value
        panel.allow_late.value = True
        panel.start("stale")
        assert until(lambda: panel.report is not None and not panel.busy, 30, panel.refresh)
        assert seen[0].allow_late is True
        assert until(lambda: "Late:" in panel.messages.text, 5, panel.refresh)
        text = panel.messages.text
        assert "tick 'allow late transitions'" in text.lower() and "--" not in text
        assert "frame 2 → frame 3 (k1 → k4) at 0.80 s: needs 0.62 s, given 0.25 s" in text
        assert "0.7999" not in text
    finally:
        panel.close()


def test_the_budgets_list_offers_the_presets_and_the_choice_reaches_the_run(state, monkeypatch):
    """The budgets list names the presets of ``--preset`` (the studio's chosen when the panel runs on it); a panel
    opened on budgets of its own lists those first; the budgets chosen are the run's, and the list is locked while
    it runs."""
    studio = optimise_panel(state, OptimiseConfig(warm_index=False))
    assert studio.budget.value == STUDIO and [v for _, v in studio.budget.options] == list(PRESETS)
    studio.close()
    panel = optimise_panel(state, OptimiseConfig(sequence=TINY, warm_index=False))
    seen, release = [], threading.Event()

    def run(cfg, **kwargs):
        seen.append(cfg.sequence)
        release.wait(10)
        return RunReport(str(state.project.path), message="done")

    monkeypatch.setattr(state.project, "run", run)
    try:
        assert [v for _, v in panel.budget.options] == [None, *PRESETS] and panel.budget.value is None
        assert "paper: the paper's method" in panel.budget.options[2][0]
        no_gpu, gpu = budget_list(TINY, gpu=False).options, budget_list(TINY, gpu=True).options
        assert "no GPU here: its search is 938× the studio's" in no_gpu[2][0] and "no GPU" not in gpu[2][0]
        assert "no GPU" not in no_gpu[1][0]  # the studio's own preset is the CPU's
        asked = budget_list(PRESETS["paper"])  # GPU or not asked of torch in the background, the choice kept
        import torch

        if not torch.cuda.is_available():
            assert until(lambda: "no GPU here" in asked.options[1][0], 30) and asked.value == "paper"
        for choice, want in ((None, TINY), ("paper", PRESETS["paper"]), (STUDIO, PRESETS[STUDIO])):
            panel.budget.value = choice
            panel.start("stale")
            assert until(lambda: len(seen) == 1, 10, panel.refresh) and seen.pop() == want, choice
            assert panel.budget.disabled  # a run goes on with the budgets it started with
            release.set()
            assert until(lambda: not panel.busy, 10, panel.refresh)
            release.clear()
            assert not panel.budget.disabled
    finally:
        release.set()
        panel.close()


def test_keyframes_posed_again_last_to_first_show_each_ones_own_target_beside_its_shadow(tmp_path):
    """The job refining a stretch together poses it again last to first with live shadows: the target shown beside
    each is the keyframe its stage names, not the stretch's first."""
    from studio.targets.keyframes import KeyframeConfig
    from studio.targets.video import DEFAULT_VIDEO

    project = Project.create(tmp_path / "horse.shadow", sources=[DEFAULT_VIDEO], roll=0,
                             clustering=KeyframeConfig(tau=0.9))  # fmt: skip
    state = StudioState(project, queue_for(project))
    panel = optimise_panel(state, OptimiseConfig(sequence=TINY, warm_index=False))
    ids = [kf.id for kf in project.keyframes][:3]
    assert len(ids) == 3
    pictures = [mask_picture(project.keyframe_masks(k)[0], panel.cfg.image_px) for k in ids]
    assert len(set(pictures)) == 3  # three targets that differ
    job = Job("imitate-together", lambda report, cancel: None, title="keyframes together", meta={"keyframes": ids})
    job.id = 21
    shadow = np.zeros((64, 64), np.uint8)
    try:
        panel.jobs = [job]

        def draw(stage: str, item: str) -> None:
            panel._draw_event(JobEvent(21, "imitate-together", JobState.RUNNING, stage, 1, 2, 0.3, shadow, 1.0, 0,
                                       item=item))  # fmt: skip

        for place, k in [(3, 2), (2, 1), (1, 0)]:
            stage = f"last to first: keyframe {ids[k]} ({place} of 3): search"
            draw(stage, str(ids[k]))  # the report names its keyframe's id
            assert panel.target_image.value == pictures[k], stage
        draw("last to first: keyframe 99 (3 of 3): search", "99")  # not one of the job's: its first keyframe's
        assert panel.target_image.value == pictures[0]
    finally:
        panel.close()
        state.close()


def test_the_jobs_list_names_a_job_once():
    """The jobs list writes a job's title where it says what the job does, its kind before it where not: never
    "play play horse" nor "preview show preview"."""
    assert job_name("play", "play horse") == "play horse"
    assert job_name("preview", "show preview") == "show preview"
    assert job_name("index", "retrieval index (first use only)") == "retrieval index (first use only)"
    assert job_name("imitate-keyframes", "keyframe 0") == "imitate-keyframes keyframe 0"
    assert job_name("plan", "show") == "plan show"
    assert job_name("plan", "") == "plan"
    assert job_name("imitate-keyframe", "imitate keyframe 2") == "imitate keyframe 2"
