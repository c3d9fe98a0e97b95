"""The retrieval index built in the background when the studio opens (widgets.index_warmup), and the line that says
how it goes: a build started once per machine, its progress, and a wait for another process's build said as such."""

from __future__ import annotations

from studio.assets import asset
from test_widgets_optimise import TINY, until

from studio.imitate.index_cache import WAITING
from studio.jobs import JobState
from studio.jobs.events import JobEvent
from studio.project.jobs import queue_for
from studio.project.project import Project
from widgets.index_warmup import IndexWarmup
from widgets.optimise import OptimiseConfig, optimise_panel
from widgets.state import StudioState


def test_the_retrieval_index_is_built_in_the_background_when_the_studio_opens(tmp_path, monkeypatch):
    """No index cached on this machine: opening the panel starts its build as a job on the project's queue, with
    its own progress line; once cached, another studio starts nothing."""
    from studio.imitate.retrieval import RetrievalConfig

    monkeypatch.setenv("SHADOW_STUDIO_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv("SHADOW_STUDIO_NO_INDEX_WARMUP", raising=False)  # the suite turns it off (conftest)
    small = RetrievalConfig(size=300, chunk=150, seed=7)
    project = Project.create(tmp_path / "i.shadow", sources=[asset("targets/asl_o.jpeg")], roll=0)
    s = StudioState(project, queue_for(project))
    heard: list[JobEvent] = []
    s.queue.subscribe(heard.append)
    panel = optimise_panel(s, OptimiseConfig(sequence=TINY, index=small))
    try:
        assert panel.warmup.checked.wait(60) and panel.warmup.job is not None
        job = panel.warmup.job
        assert job.kind == "index" and s.extras["index_job"] is job and job.wait(120) == JobState.DONE, job.error
        assert job.result == 300 and list((tmp_path / "cache" / "retrieval").glob("index-*.npz"))
        assert any(e.job_id == job.id and e.stage == "index" and e.total == 300 for e in heard)
        assert until(lambda: "retrieval index is ready" in panel.warmup.line.value, 10, panel.refresh)
        assert panel.jobs == [] and not panel.busy  # not an optimisation: the buttons stay usable
    finally:
        panel.close()
        s.close()
    again = StudioState(Project.open(project.path), queue_for(Project.open(project.path)))
    other = optimise_panel(again, OptimiseConfig(sequence=TINY, index=small))
    try:
        assert other.warmup.checked.wait(60)
        assert other.warmup.job is None and again.queue.jobs() == [] and "index_job" not in again.extras
    finally:
        other.close()
        again.close()


def test_the_line_says_when_another_process_builds_the_index_and_when_it_is_ready(tmp_path):
    """A build that waits for another process's (studio.imitate.index_cache) says so on the line, then ready."""
    project = Project.create(tmp_path / "w.shadow", sources=[asset("targets/asl_o.jpeg")], roll=0)
    s = StudioState(project, queue_for(project))
    try:
        warmup = IndexWarmup(s)
        nan = float("nan")
        warmup.draw(JobEvent(3, "index", JobState.RUNNING, "index", 0, 200_000, nan, None, 1.0, 1, item=WAITING))
        assert "retrieval index of 200,000 poses (first use only, cached): waiting for another process or job" in (
            warmup.line.value
        )
        warmup.draw(JobEvent(3, "index", JobState.DONE, "index", 200_000, 200_000, nan, None, 9.0, 2))
        assert "the retrieval index is ready (cached)" in warmup.line.value
    finally:
        s.close()
