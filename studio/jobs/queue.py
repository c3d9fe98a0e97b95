"""One queue of background jobs per project: FIFO, one job at a time, results applied only on completion.

    queue = JobQueue()                                   # worker="thread" (benchmarks/bench_jobs.py chose it)
    queue.subscribe(lambda e: ...)                       # called on the queue's thread: keep it cheap
    job = queue.submit(Job("imitate-keyframe", run, apply=lambda r: project.set_result(k, r)))
    queue.events()                                       # or pull: every event since the last call
    job.cancel()                                         # final event "cancelled" within 1 s, nothing applied

A job's ``run(report, cancel) -> result`` runs in the worker; ``apply(result)`` runs once, on the queue's
dispatcher thread, only when ``run`` returned and the job was not cancelled; the job is ``done`` after it. A job that
raises (in ``run`` or ``apply``) ends ``failed`` with a :class:`~studio.jobs.events.JobError`, a cancelled
one ``cancelled``: neither calls ``apply``, so the project stays exactly as it was (an ``apply`` that raises halfway
must keep its own edits atomic: the Project API's are). A cancelled job's partial result (the engines return the
best so far) stays readable in :attr:`Job.result` for whoever wants it; it is never applied.

Cancel: the engine's cancel event is set at once; a job that has not ended ``cancel_grace`` s later is given up
(a process worker is killed, a thread is left to reach its next check and its result ignored; the next job waits
for it) and reported ``cancelled``, so the final event always comes within a second.
"""

from __future__ import annotations

import logging
import threading
import time
import traceback
from collections import deque
from collections.abc import Callable

from studio.jobs.events import EventPoller, JobError, JobEvent, JobState, WorkerDied
from studio.jobs.job import Job
from studio.jobs.workers import WORKERS, ProcessWorker, ThreadWorker
from studio.learn.threads import DEFAULT_THREADS

log = logging.getLogger(__name__)

DEFAULT_WORKER = "thread"  # benchmarks/bench_jobs.py: p99 1.4 ms (search) / 5.3 ms (refine); figures in the package doc
Subscriber = Callable[[JobEvent], None]


class JobQueue:
    """The jobs of one project (module doc). ``worker``: "thread", "process" or a worker object."""

    def __init__(self, worker: str | ThreadWorker | ProcessWorker = DEFAULT_WORKER,
                 threads: int | None = DEFAULT_THREADS, cancel_grace: float = 0.8):  # fmt: skip
        if isinstance(worker, str):
            if worker not in WORKERS:
                raise ValueError(f"worker must be one of {sorted(WORKERS)}, not {worker!r}")
            worker = WORKERS[worker](threads)
        self.worker = worker  # where run() executes
        self.cancel_grace = cancel_grace  # s a cancelled job may take before it is given up (< 1)
        self._jobs: list[Job] = []
        self._pending: deque[Job] = deque()
        self._cond = threading.Condition()
        self._subscribers: list[Subscriber] = []
        self._pollers: list[EventPoller] = []
        self._own_poller = self.poller()
        self._thread: threading.Thread | None = None
        self._closed = False
        self._straggler = None  # an abandoned thread runner the next job waits for

    # --- consumers ---------------------------------------------------------------------------------------------
    def subscribe(self, callback: Subscriber) -> Callable[[], None]:
        """Call ``callback(event)`` for every event, on the thread that emits it (keep it cheap; a raising callback
        is logged, never stops a job). Returns a function that unsubscribes it."""
        with self._cond:
            self._subscribers = [*self._subscribers, callback]

        def unsubscribe() -> None:
            with self._cond:
                self._subscribers = [s for s in self._subscribers if s is not callback]

        return unsubscribe

    def poller(self, maxlen: int = 10_000) -> EventPoller:
        """A new pull consumer that receives every event from now on."""
        p = EventPoller(maxlen)
        with self._cond:
            self._pollers = [*self._pollers, p]
        return p

    def events(self, timeout: float = 0.0) -> list[JobEvent]:
        """Every event since the last call (the queue's own poller), waiting up to ``timeout`` s for one."""
        return self._own_poller.poll(timeout)

    # --- jobs --------------------------------------------------------------------------------------------------
    def submit(self, job: Job) -> Job:
        """Queue ``job`` (FIFO) and return it, numbered. A process worker checks here that it pickles."""
        if self._closed:
            raise RuntimeError("this JobQueue was closed; make a new one")
        if job._queue is not None:
            raise ValueError(f"{job!r} was already submitted; make a new Job to run it again")
        self.worker.check(job.run)
        with self._cond:
            job.id, job._queue = len(self._jobs) + 1, self
            self._jobs.append(job)
            self._emit(job, JobState.QUEUED)
            self._pending.append(job)
            self._cond.notify_all()
            if self._thread is None:
                self._thread = threading.Thread(target=self._dispatch, name="studio-jobs", daemon=True)
                self._thread.start()
        return job

    def jobs(self) -> list[Job]:
        """Every job submitted, in order, with its state."""
        with self._cond:
            return list(self._jobs)

    def table(self) -> list[dict]:
        """:meth:`Job.info` of every job (for listings and JSON)."""
        return [j.info() for j in self.jobs()]

    def get(self, job_id: int) -> Job:
        with self._cond:
            if not 1 <= job_id <= len(self._jobs):
                raise KeyError(f"no job #{job_id} in this queue (it has {len(self._jobs)})")
            return self._jobs[job_id - 1]

    def cancel_all(self) -> None:
        """Cancel every queued and running job."""
        for job in self.jobs():
            job.cancel()

    def wait(self, timeout: float | None = None) -> bool:
        """Block until every submitted job finished (or ``timeout`` s passed); True when idle."""
        deadline = None if timeout is None else time.monotonic() + timeout
        for job in self.jobs():
            left = None if deadline is None else max(0.0, deadline - time.monotonic())
            if not job._done.wait(left):
                return False
        return True

    def run(self, job: Job, timeout: float | None = None) -> Job:
        """Submit ``job`` and wait for it (the CLI's foreground run). Ctrl-C cancels it, waits for its final
        event, and re-raises KeyboardInterrupt."""
        self.submit(job)
        try:
            job.wait(timeout)
        except KeyboardInterrupt:
            job.cancel()
            job.wait(2.0)
            raise
        return job

    def close(self) -> None:
        """Cancel everything, stop the dispatcher and the worker (idempotent)."""
        if self._closed:
            return
        self.cancel_all()
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(5.0)
        self.worker.close()

    def __enter__(self) -> JobQueue:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- the dispatcher ----------------------------------------------------------------------------------------
    def _emit(self, job: Job, state: JobState, stage: str | None = None, step: int | None = None,
              total: int | None = None, best: float | None = None, shadow=None,
              error: JobError | None = None, item: str | None = None) -> None:  # fmt: skip
        with job._lock:
            job.state = state
            job.stage = job.stage if stage is None else stage
            job.step = job.step if step is None else step
            job.total = job.total if total is None else total
            job.best = job.best if best is None else best
            job.item = job.item if item is None else item
            job.shadow = job.shadow if shadow is None else shadow
            if state.finished:
                job.error, job.ended = error, time.monotonic()
            event = JobEvent(job.id, job.kind, state, job.stage, job.step, job.total, job.best, shadow,
                             job.elapsed, job._seq, error, job.item)  # fmt: skip
            job._seq += 1
            for poller in self._pollers:
                poller.put(event)
            for callback in self._subscribers:
                try:
                    callback(event)
                except Exception:
                    log.exception("a job event subscriber raised (ignored)")
            if state.finished:
                job._done.set()

    def _finish(self, job: Job, state: JobState, error: JobError | None = None) -> None:
        self._emit(job, state, error=error)

    def _dispatch(self) -> None:
        while True:
            with self._cond:
                while not self._pending and not self._closed:
                    self._cond.wait()
                if self._closed and not self._pending:
                    return
                job = self._pending.popleft()
            if self._straggler is not None:  # an abandoned thread still running: one job at a time
                self._straggler.join()
                self._straggler = None
            with job._lock:
                if job.state != JobState.QUEUED:  # cancelled while queued
                    continue
                job.started = time.monotonic()
                self._emit(job, JobState.RUNNING, stage="start", item="")
                try:
                    job._runner = self.worker.start(job.run)
                except Exception as e:
                    self._finish(job, JobState.FAILED, JobError(type(e).__name__, str(e), ""))
                    continue
            self._follow(job, job._runner)

    def _follow(self, job: Job, runner) -> None:
        """Turn the runner's messages into events until its final one (or the cancel grace runs out)."""
        while True:
            msg = runner.get(0.05)
            if msg is None:
                if job._cancel.is_set() and time.monotonic() - job._cancel_at > self.cancel_grace:
                    runner.abandon()
                    if not runner.join(0):
                        self._straggler = runner
                    return self._finish(job, JobState.CANCELLED)
                if not runner.alive():
                    why = WorkerDied(f"the worker process of job #{job.id} ended without an answer; run it again")
                    return self._finish(job, JobState.FAILED, JobError("WorkerDied", str(why), ""))
                continue
            kind = msg[0]
            if kind == "progress":
                _, stage, step, total, best, shadow, item = msg
                self._emit(job, JobState.RUNNING, stage, step, total, best, shadow, item=item)
            elif kind == "error":
                return self._finish(job, JobState.FAILED, JobError(msg[1], msg[2], msg[3]))
            elif kind == "cancelled" or job._cancel.is_set():
                job.result = msg[1] if kind == "done" else None
                return self._finish(job, JobState.CANCELLED)
            else:
                job.result = msg[1]
                return self._apply(job)

    def _apply(self, job: Job) -> None:
        with job._lock:
            if job._cancel.is_set():
                return self._finish(job, JobState.CANCELLED)
            job._applying = True  # a cancel from now on comes too late
            self._emit(job, JobState.RUNNING, stage="apply", item="")
        try:
            if job.apply_fn is not None:
                job.apply_fn(job.result)
        except Exception as e:
            return self._finish(job, JobState.FAILED, JobError(type(e).__name__, str(e), traceback.format_exc()))
        job.applied = True
        self._finish(job, JobState.DONE)
