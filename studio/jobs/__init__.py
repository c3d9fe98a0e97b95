"""Background work (DESIGN §3, §5.11): the engine in a worker, typed progress events, cancel within a second,
results applied only on completion. Knows nothing of projects (:mod:`studio.project.jobs` binds jobs to one).

    from studio.jobs import JobQueue, TqdmBars, imitate_keyframe_job
    with JobQueue() as queue:                             # FIFO, one job at a time
        queue.subscribe(TqdmBars())                       # the one tqdm subscriber (CLI); widgets subscribe or poll
        job = queue.submit(imitate_keyframe_job("asl_v.jpeg", apply=lambda r: ...))
        job.wait()                                        # job.state: done / failed (job.error) / cancelled

Pieces: :mod:`.events` (JobEvent, JobState, JobError, Reporter, PosePreview, EventPoller), :mod:`.job` (Job),
:mod:`.queue` (JobQueue), :mod:`.workers` (thread and spawned-process workers), :mod:`.engine` (imitate a keyframe,
imitate a sequence of keyframes, refine them together, choose the mount roll, plan a show), :mod:`.bars` (tqdm).

**Thread or process?** ``benchmarks/bench_jobs.py`` on this 2-core machine (shared with other work), the main
thread's asyncio loop ticking every 20 ms for 10 s while a job runs (lateness p50 / p99, ms):

| job stage | no job | thread worker | process worker (spawn) |
|---|---|---|---|
| gradient search (32 × ∞, 1 torch thread) | 0.61 / 1.28 | 0.66 / 1.40 | 0.68 / 2.09 |
| refinement (numba renderer + PyBullet) | 0.62 / 1.33 | 0.66 / 5.30 | 0.59 / 1.13 |

Both keep p99 far under the 100 ms target: torch releases the GIL in its kernels and CPython's 5 ms switch interval
bounds the rest (the refinement's p99 is that interval). The search ran as fast in either (19.4 vs 18.4 steps/s);
the process took ~1 s longer to start (3.1 vs 2.2 s: a fresh interpreter imports torch and loads the model for every
new worker), needs picklable jobs and results, and cannot hold a caller's bus or hooks. So the default is the
**thread** worker (``DEFAULT_WORKER``); ``JobQueue("process")`` remains for work that must be killable at once
(a cancelled job that does not stop within the grace time is killed, not waited for) or isolated from crashes.

A job's torch work runs on ``threads`` (:data:`studio.learn.threads.DEFAULT_THREADS`: 2 on 2 cores). Rerun with
``--workers thread --threads 1|2``: the search 13.8 → 18.4 steps/s, the main thread's p99 1.26 → 3.47 ms.
"""

from __future__ import annotations

from studio.jobs.bars import TqdmBars
from studio.jobs.engine import PlannedShow, imitate_keyframe_job, imitate_video_job, plan_job
from studio.jobs.events import (
    EventPoller,
    JobCancelled,
    JobError,
    JobEvent,
    JobState,
    PosePreview,
    Reporter,
    WorkerDied,
)  # fmt: skip
from studio.jobs.job import Job
from studio.jobs.queue import DEFAULT_WORKER, JobQueue

__all__ = [
    "DEFAULT_WORKER", "EventPoller", "Job", "JobCancelled", "JobError", "JobEvent", "JobQueue", "JobState",
    "PlannedShow", "PosePreview", "Reporter", "TqdmBars", "WorkerDied", "imitate_keyframe_job", "imitate_video_job",
    "plan_job",
]  # fmt: skip
