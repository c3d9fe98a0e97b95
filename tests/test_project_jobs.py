"""Jobs bound to a project (studio.project.jobs): applied through the Project API on completion, nothing on cancel
or failure (every file's bytes, the results and the undo list unchanged); a result whose inputs changed while it
waited is applied stale; the show job sets the show."""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np
import pytest
from jobs_support import LONG, TARGET, TINY, Recorder  # the job tests' own helpers, beside this file

from studio.imitate.config import RefineConfig
from studio.jobs import JobState


@pytest.fixture
def project(tmp_path):
    from studio.project.project import Project

    return Project.create(tmp_path / "still.shadow", sources=[TARGET])


def snapshot(project) -> tuple:
    """What must not change: every file's bytes, the results, the undo list."""
    files = {p.relative_to(project.path): p.read_bytes() for p in sorted(project.path.rglob("*")) if p.is_file()}
    return files, dict(project.results), project.history


@pytest.mark.slow
def test_project_jobs_apply_on_completion_and_nothing_on_cancel_or_failure(project, tmp_path, hand):
    from studio.imitate.config import CPU_SEQUENCE
    from studio.project.jobs import queue_for, video_job

    def one(search, model_path=None, **kw):  # keyframe k alone, searched from scratch (no retrieval index to build)
        return video_job(project, [k], cfg=replace(CPU_SEQUENCE, first=search, retrieve=False, **kw),
                         model_path=model_path)  # fmt: skip

    k = project.keyframes[0].id
    before = snapshot(project)
    queue = queue_for(project)
    assert queue_for(project) is queue
    rec = Recorder("search")
    queue.subscribe(rec)
    try:
        job = queue.submit(one(LONG))
        assert rec.seen.wait(60), job.error
        t0 = time.monotonic()
        job.cancel()
        assert job.wait(1.0) == JobState.CANCELLED and time.monotonic() - t0 < 1.0
        broken = tmp_path / "broken.pt"
        broken.write_bytes(b"not a checkpoint")
        failed = queue.run(one(TINY, model_path=broken))
        assert failed.state == JobState.FAILED and failed.error.message
        assert snapshot(project) == before and not project.can_undo

        done = queue.run(one(TINY, refine=RefineConfig(steps=10), candidates=1))
        assert done.state == JobState.DONE, done.error
        assert np.allclose(project.results[k].theta(hand.joint_names), done.result.keyframes[0].theta)
        assert np.array_equal(project.results[k].shadow, done.result.keyframes[0].shadow)
        assert project.pending_keyframes() == [] and project.history[-1] == f"result of keyframe {k}"
        project.undo()
        assert k not in project.results

        cfg = replace(CPU_SEQUENCE, first=TINY, refine=RefineConfig(steps=5), candidates=1)
        seq = queue.run(video_job(project, cfg=cfg))
        assert seq.state == JobState.DONE, seq.error
        assert project.pending_keyframes() == [] and k in project.results
    finally:
        queue.close()


@pytest.mark.slow
def test_project_results_from_changed_inputs_are_stale_and_the_show_is_set(project, hand):
    from studio.imitate.config import CPU_SEQUENCE
    from studio.motion.plan import Keyframes
    from studio.project.jobs import queue_for, show_job, video_job

    k = project.keyframes[0].id
    with queue_for(project) as queue:
        tiny = replace(CPU_SEQUENCE, first=TINY, refine=RefineConfig(steps=10), candidates=1, retrieve=False)
        job = video_job(project, [k], cfg=tiny)
        project.set_weights(w_iou=0.5)  # the artist edits while the job waits: its inputs were captured before
        assert queue.run(job).state == JobState.DONE, job.error
        assert project.is_stale(k) and project.stale_keyframes() == [k]
        pose = hand.rest_pose().copy()
        pose[hand.joint_names.index("index_pip")] = 0.6  # a collision-free pose (the tiny search's may not be)
        plan = queue.run(show_job(project, Keyframes.at([0.5], [pose])))
        assert plan.state == JobState.DONE, plan.error
    assert project.show is not None and not project.is_show_stale()
    assert np.allclose(project.show.positions[-1], pose) and project.history[-1] == "planned show"
