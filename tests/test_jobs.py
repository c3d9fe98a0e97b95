"""Background jobs (studio.jobs): cancel within 1 s applying nothing, failures reported and applying nothing, FIFO
one at a time with the right states, ordered events consumed by tqdm and by polling, apply exactly once; the engine
jobs run the real engine (tiny searches), the play job real pyserial against the emulator. Jobs bound to a project
(studio.project.jobs): tests/test_project_jobs.py."""

from __future__ import annotations

import io
import math
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
from jobs_support import LONG, TARGET, TINY, Recorder  # the job tests' own helpers, beside this file
from studio.assets import asset

from studio.imitate.config import RefineConfig
from studio.jobs import (
    Job,
    JobQueue,
    JobState,
    PlannedShow,
    TqdmBars,
    imitate_keyframe_job,
    imitate_video_job,
    plan_job,
)
from studio.project.play import play_job


def staged(stages, release: threading.Event | None = None, log: list | None = None, name: str = ""):
    """A plain job: reports ``stages`` [(stage, total)], step by step, optionally waiting for ``release`` first."""

    def run(report, cancel):
        if log is not None:
            log.append(("start", name, time.monotonic()))
        if release is not None:
            while not release.wait(0.01):
                if cancel.is_set():
                    return None
        for stage, total in stages:
            for i in range(1, total + 1):
                report(stage, i, total, 1.0 / i)
        if log is not None:
            log.append(("end", name, time.monotonic()))
        return name

    return run


@pytest.mark.slow
def test_cancel_mid_search_returns_within_a_second_and_applies_nothing():
    applied, rec = [], Recorder("search")
    with JobQueue() as queue:
        queue.subscribe(rec)
        job = queue.submit(imitate_keyframe_job(TARGET, search=LONG, apply=applied.append))
        assert rec.seen.wait(60), f"the search never started: {job.state} {job.error}"
        time.sleep(0.2)
        t0 = time.monotonic()
        assert job.cancel()
        assert job.wait(1.0) == JobState.CANCELLED
        assert time.monotonic() - t0 < 1.0
    assert applied == [] and not job.applied
    assert job.result is not None and job.result.cancelled  # the best pose so far stays readable, not applied
    assert rec.events[-1].state == JobState.CANCELLED and rec.events[-1].final
    assert not job.cancel()  # finished: nothing more to cancel


def test_failing_jobs_report_their_error_and_apply_nothing(tmp_path):
    bad = tmp_path / "not_an_image.png"
    bad.write_bytes(b"this is no PNG")
    applied = []

    def raising(report, cancel):
        report("search", 1, 10, 0.5)
        raise ValueError("the engine broke at step 1")

    with JobQueue() as queue:
        a = queue.submit(imitate_keyframe_job(bad, search=TINY, apply=applied.append))
        b = queue.submit(Job("custom", raising, apply=applied.append))
        c = queue.submit(Job("custom", staged([("s", 2)]), apply=lambda r: (_ for _ in ()).throw(KeyError("no k"))))
        assert queue.wait(60)
    assert a.state == JobState.FAILED and a.error.type == "TargetError" and "not_an_image.png" in a.error.message
    assert "Traceback" in a.error.traceback and "TargetError" in a.error.traceback
    assert b.state == JobState.FAILED and str(b.error) == "ValueError: the engine broke at step 1"
    assert c.state == JobState.FAILED and c.error.type == "KeyError" and not c.applied  # apply raised
    assert applied == []
    assert [row["state"] for row in queue.table()] == ["failed"] * 3
    assert queue.table()[1]["error"] == "ValueError: the engine broke at step 1"


def test_queue_runs_jobs_fifo_one_at_a_time_with_their_states():
    release, log = threading.Event(), []
    with JobQueue() as queue:
        jobs = [queue.submit(Job("custom", staged([("s", 3)], release, log, f"j{i}"), title=f"j{i}")) for i in range(3)]
        doomed = queue.submit(Job("custom", staged([("s", 1)], log=log, name="doomed")))
        deadline = time.monotonic() + 10
        while jobs[0].state != JobState.RUNNING and time.monotonic() < deadline:
            time.sleep(0.01)
        assert [j.state for j in queue.jobs()] == [JobState.RUNNING] + [JobState.QUEUED] * 3
        assert doomed.cancel() and doomed.state == JobState.CANCELLED  # cancelled while queued: at once
        release.set()
        assert queue.wait(10)
    assert [j.state for j in jobs] == [JobState.DONE] * 3 and [j.result for j in jobs] == ["j0", "j1", "j2"]
    assert [(what, name) for what, name, _ in log] == [(w, f"j{i}") for i in range(3) for w in ("start", "end")]
    times = [t for _, _, t in log]
    assert times == sorted(times)  # each job started after the previous one ended
    assert [r["id"] for r in queue.table()] == [1, 2, 3, 4] and queue.get(4).state == JobState.CANCELLED


def test_events_carry_stage_step_total_in_order():
    rec = Recorder()
    with JobQueue() as queue:
        queue.subscribe(rec)
        job = queue.submit(Job("custom", staged([("first", 3), ("second", 2)])))
        queue.submit(Job("custom", staged([("other", 1)])))
        assert queue.wait(10)
    mine = [e for e in rec.events if e.job_id == job.id]
    assert [e.seq for e in mine] == list(range(len(mine)))
    assert [e.state for e in mine] == [JobState.QUEUED] + [JobState.RUNNING] * 7 + [JobState.DONE]
    progress = [(e.stage, e.step, e.total) for e in mine[2:7]]
    assert progress == [("first", 1, 3), ("first", 2, 3), ("first", 3, 3), ("second", 1, 2), ("second", 2, 2)]
    assert mine[2].best == 1.0 and mine[3].fraction == pytest.approx(2 / 3)
    assert all(b.elapsed >= a.elapsed for a, b in zip(mine, mine[1:]))
    assert math.isnan(mine[0].best) and mine[0].elapsed == 0.0  # queued: nothing yet
    end = rec.events.index(mine[-1])
    assert all(rec.events.index(e) > end for e in rec.events if e.job_id == 2 and e.state != JobState.QUEUED)


def test_follow_returns_once_every_subscriber_was_told_the_end():
    """A run that follows its jobs (studio.project.run) reports after the panels drew their final events: ``follow``
    returns only once the last subscriber has the job's final event, however long it takes over it."""
    told: list[JobState] = []

    def slow_subscriber(e) -> None:
        if e.final:
            time.sleep(0.3)  # longer than follow's 0.1 s look: the state is DONE meanwhile
            told.append(e.state)

    with JobQueue() as queue:
        queue.subscribe(slow_subscriber)
        job = queue.submit(Job("custom", staged([("s", 2)])))
        assert job.follow(None) == JobState.DONE
        assert told == [JobState.DONE]


@pytest.mark.slow
def test_engine_events_feed_tqdm_and_a_poller_alike():
    out, rec = io.StringIO(), Recorder()
    with JobQueue() as queue:
        poller = queue.poller()
        queue.subscribe(TqdmBars(file=out, mininterval=0))
        queue.subscribe(rec)
        job = queue.submit(imitate_keyframe_job(TARGET, search=TINY, refine=RefineConfig(steps=10), candidates=1))
        assert job.wait(60) == JobState.DONE, job.error
        pulled = poller.poll(timeout=1.0)
    assert [(e.job_id, e.seq) for e in pulled] == [(e.job_id, e.seq) for e in rec.events]
    stages = [e.stage for e in pulled if e.stage in ("search", "refine")]
    assert stages[0] == "search" and stages[-1] == "refine"
    search = [(e.step, e.total) for e in pulled if e.stage == "search"]
    assert search == [(5, 20), (10, 20), (15, 20), (20, 20)]
    text = out.getvalue()
    assert "#1 imitate-keyframe: search" in text and "20/20" in text and "#1 imitate-keyframe: refine" in text
    assert "best 0." in text
    shadows = [e.shadow for e in pulled if e.shadow is not None]
    assert shadows and all(s.dtype == np.uint8 and s.shape == (64, 64) and s.any() for s in shadows)
    assert len(shadows) <= job.elapsed * 10 + 2  # at most ~10 previews a second
    assert np.array_equal(job.shadow, shadows[-1])


@pytest.mark.slow
def test_a_keyframe_job_on_a_rolled_mount_casts_and_previews_the_rolled_shadow():
    import math

    from studio.sim.hand import load_hand
    from studio.sim.shadow import Rig, ShadowRenderer

    roll = math.radians(40.0)
    with JobQueue() as queue:
        job = queue.run(imitate_keyframe_job(TARGET, search=TINY, refine=RefineConfig(steps=5), candidates=1,
                                             roll=roll), timeout=120)  # fmt: skip
    assert job.state == JobState.DONE, job.error
    got, hand = job.result, load_hand()
    rolled = ShadowRenderer(hand, Rig(resolution=128, roll=roll)).render_one(got.theta)
    assert got.roll == roll and np.array_equal(got.shadow, rolled)
    preview = ShadowRenderer(hand, Rig(resolution=64, roll=roll)).render_one(got.theta)
    assert np.array_equal(job.shadow, preview)  # the live preview is the rolled mount's too (the last pose shown)


def test_a_completed_jobs_apply_runs_once_with_its_result():
    calls, rec = [], Recorder()

    def apply(result):
        calls.append((result, threading.current_thread().name))

    with JobQueue() as queue:
        queue.subscribe(rec)
        job = queue.run(Job("custom", staged([("s", 2)], name="answer"), apply=apply))
        assert job.state == JobState.DONE and job.applied
        assert not job.cancel()  # done: too late
        assert queue.wait(1)
    assert calls == [("answer", "studio-jobs")]  # once, on the queue's thread
    assert [e.stage for e in rec.events[-2:]] == ["apply", "apply"] and rec.events[-1].state == JobState.DONE


@pytest.mark.slow
def test_imitate_video_job_runs_every_keyframe():
    from studio.imitate.config import CPU_SEQUENCE
    from studio.targets.images import load_target

    masks = np.stack([load_target(asset(f"targets/{n}.jpeg"), size=128) for n in ("asl_v", "asl_y")])
    cfg = replace(CPU_SEQUENCE, first=TINY, next=replace(TINY, iterations=10), refine=RefineConfig(steps=5),
                  candidates=1, expressive=False)  # fmt: skip
    got, rec = [], Recorder()
    with JobQueue() as queue:
        queue.subscribe(rec)
        job = queue.submit(imitate_video_job(masks, cfg=cfg, apply=got.append))
        assert job.wait(120) == JobState.DONE, job.error
    assert len(got) == 1 and len(got[0].keyframes) == 2 and not got[0].cancelled
    stages = {e.stage for e in rec.events}
    assert {"keyframe 1/2: search", "keyframe 2/2: search", "keyframe 2/2: refine"} <= stages


def test_plan_and_play_jobs(hand):
    from studio.motion.plan import Keyframes

    q = hand.rest_pose().copy()
    q[hand.joint_names.index("index_pip")] = 0.6
    got, rec = [], Recorder()
    with JobQueue() as queue:
        queue.subscribe(rec)
        plan = queue.run(plan_job(Keyframes.at([0.5], [q]), apply=got.append))
        assert plan.state == JobState.DONE, plan.error
        planned = got[0]
        assert isinstance(planned, PlannedShow) and planned.home_added
        assert np.allclose(planned.show.positions[-1], q)
        play = queue.run(play_job(planned.show, apply=got.append))
        assert play.state == JobState.DONE, play.error
    assert got[1].ok and got[1].commands > 0
    steps = [(e.stage, e.step, e.total) for e in rec.events if e.job_id == plan.id and e.state == JobState.RUNNING]
    steps = [s for s in steps if s[0] not in ("start", "apply")]
    assert steps == [("keyframes", 0, 2), ("keyframes", 2, 2), ("path", 1, 3), ("path", 2, 3), ("path", 3, 3),
                     ("timing", 1, 1), ("show", 1, 1)]  # fmt: skip
    ticks = [(e.step, e.total) for e in rec.events if e.job_id == play.id and e.stage == "play"]
    assert ticks and ticks[-1][0] == ticks[-1][1]


def test_cancel_mid_plan_ends_the_job_cancelled_within_a_second(hand):
    """plan_show gets the job's cancel event: a cancel while the path is repaired (seconds of work) ends the job
    cancelled within a second, nothing applied."""
    from studio.motion.plan import Keyframes

    j = hand.joint_names.index
    a = hand.rest_pose().copy()
    a[[j("index_mcp_abd"), j("index_mcp_flex"), j("index_pip")]] = (-0.39, -1.52, 0.12)
    a[[j("middle_mcp_abd"), j("middle_mcp_flex"), j("middle_pip")]] = (-0.55, -0.7, 0.36)
    b = a.copy()
    b[[j("index_mcp_abd"), j("index_mcp_flex")]] = (-0.29, 0.53)  # the index finger swings across the middle one
    got, rec = [], Recorder("path")
    with JobQueue() as queue:
        queue.subscribe(rec)
        job = queue.submit(plan_job(Keyframes.at([1.0, 4.0, 7.0, 10.0], [a, b, a, b], hold=False), apply=got.append))
        assert rec.seen.wait(60), job.error
        t0 = time.monotonic()
        assert job.cancel()
        assert job.wait(1.0) == JobState.CANCELLED and time.monotonic() - t0 < 1.0
    assert got == [] and job.error is None and rec.events[-1].state == JobState.CANCELLED
    assert "timing" not in {e.stage for e in rec.events}  # stopped within the path, not at its end


def test_plan_job_with_a_colliding_keyframe_fails_with_the_planners_error(hand):
    from studio.motion.plan import Keyframes
    from studio.sim.physics import CollisionWorld

    rng = np.random.default_rng(0)
    with CollisionWorld(hand) as world:
        bad = next(p for p in rng.uniform(hand.lower, hand.upper, (500, hand.dof)) if world.in_collision(p)[0])
    got = []
    with JobQueue() as queue:
        job = queue.run(plan_job(Keyframes.at([1.0], [bad]), apply=got.append))
    assert job.state == JobState.FAILED and job.error.type == "KeyframeCollisionError" and got == []


def test_cancel_during_play_stops_the_player():
    from studio.motion.show import Show
    from studio.sim.hand import load_hand

    hand = load_hand()
    t = np.arange(0, 20, 1 / 40)
    show = Show.from_samples(hand, t, np.tile(hand.rest_pose(), (len(t), 1)), title="still 20 s")
    rec, got = Recorder("play"), []
    with JobQueue() as queue:
        queue.subscribe(rec)
        job = queue.submit(play_job(show, apply=got.append))
        assert rec.seen.wait(30), job.error
        t0 = time.monotonic()
        job.cancel()
        assert job.wait(1.0) == JobState.CANCELLED and time.monotonic() - t0 < 1.0
    assert got == [] and job.result is not None and job.result.reason.value == "cancelled"


def sleeper(report, cancel):
    """Engine code that ignores its cancel event (a process worker must kill it)."""
    report("sleep", 0, 1)
    time.sleep(60)


def echo(report, cancel, value):
    report("echo", 1, 1)
    return value


@pytest.mark.slow
def test_process_worker_kills_an_unresponsive_job_and_runs_the_next():
    import functools

    applied = []
    with JobQueue("process") as queue:
        with pytest.raises(TypeError, match="picklable"):
            queue.submit(Job("custom", lambda report, cancel: None))
        rec = Recorder("sleep")
        queue.subscribe(rec)
        stuck = queue.submit(Job("custom", sleeper, apply=applied.append))
        after = queue.submit(Job("custom", functools.partial(echo, value={"a": np.arange(3)}), apply=applied.append))
        assert rec.seen.wait(60), stuck.error
        t0 = time.monotonic()
        stuck.cancel()
        assert stuck.wait(1.0) == JobState.CANCELLED and time.monotonic() - t0 < 1.0
        assert after.wait(60) == JobState.DONE, after.error
    assert len(applied) == 1 and np.array_equal(applied[0]["a"], np.arange(3))


def test_best_pose_hook_gives_the_reported_pose(hand):
    from studio.imitate.search import gradient_search
    from studio.imitate.still import Imitator

    seen = []
    with Imitator() as im:
        loss_fn = im.loss_fn(im.load(TARGET))
        r = gradient_search(im.model, loss_fn, TINY, progress=lambda p: seen.append(("p", p.best)),
                            best_pose=lambda th: seen.append(("pose", th)))  # fmt: skip
    kinds = [k for k, _ in seen]
    assert kinds == ["pose", "p"] * 4
    poses = [v for k, v in seen if k == "pose"]
    assert all(p.shape == (21,) and np.all(p >= hand.lower - 1e-6) and np.all(p <= hand.upper + 1e-6) for p in poses)
    assert [b for k, b in seen if k == "p"][-1] == pytest.approx(r.curve[-1][1])


# --- jobs bound to a project: applied through the Project API, nothing on failure or cancel ---------------------
