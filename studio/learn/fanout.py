"""Many items through one task: in this process, on local worker processes, or on a Ray cluster.

A *task* is a picklable object with ``setup()`` (load what every item needs: a model, a renderer; once per worker)
and ``__call__(item)`` (one item's result, picklable); ``close()`` is optional. :func:`fan_out` runs it over
``items`` and returns ``{index: result}`` for the items finished, whichever way they ran:

* ``workers == 1`` and no Ray: in this process, one item after another (the reference path);
* ``workers > 1`` and no Ray: that many spawned processes (``spawn``: numba's OpenMP pool kills a child plainly
  forked from a process that has rendered, DESIGN §4), each set up once;
* ``ray``: that many Ray actors (:mod:`studio.learn.ray_cluster`: a local Ray started for the run, or a cluster
  joined), each set up once and fed the next item as soon as it is free.

Results are keyed by the item's index, so callers gather them in order however the work was spread. An item may
lead to more: what ``on_result`` returns for a finished item joins the work (indices after the items given), so
work that must run in order (a source's keyframes, each continuing from the one before it) goes out one step at a
time and each step's result is kept the moment it comes back. Progress: stage ``stage``, step = items finished, of
``total`` (default: the items known so far; ``item``: the item's name when ``names`` gives one). ``cancel`` stops
handing out items and ends the workers (on Ray the actors are killed, so running items stop at once); the items
finished before it are returned. An error in a task is raised here as :class:`FanoutError` naming the item (one
in a worker's ``setup()``: the error, once), after the other workers are stopped. Nothing imports Ray unless
``cfg.ray`` asks for it (DESIGN §3).
"""

from __future__ import annotations

import multiprocessing
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass, replace
from typing import Any, Protocol

from studio.errors import ProgressFn, StudioError, report, stopped

__all__ = ["FanoutConfig", "FanoutError", "Task", "fan_out"]

POLL_S = 0.2  # how often a waiting fan-out looks at ``cancel``, s


@dataclass(frozen=True)
class FanoutConfig:
    """How work is spread (the ``--workers`` and ``--ray`` flags)."""

    workers: int = 1  # worker processes (or Ray actors); 1 without Ray: in this process [1, 1024]
    ray: str = ""  # "" no Ray; "local": start a local Ray for the run; an address ("auto", "host:6379"): join it
    cpus_per_worker: float = 1.0  # CPUs each Ray actor reserves (0, 256]
    gpus_per_worker: float = 0.0  # GPUs each Ray actor reserves (0: CPU only) [0, 16]

    def __post_init__(self) -> None:
        if not 1 <= self.workers <= 1024:
            raise ValueError(f"workers must be in [1, 1024], got {self.workers}")
        if not 0 < self.cpus_per_worker <= 256 or not 0 <= self.gpus_per_worker <= 16:
            raise ValueError("cpus_per_worker must be in (0, 256] and gpus_per_worker in [0, 16]")

    @property
    def where(self) -> str:
        """How the work runs, in words ("this process", "2 local processes", "2 Ray actors on a local Ray")."""
        if self.ray:
            on = "a local Ray" if self.ray == "local" else f"the Ray cluster at {self.ray}"
            return f"{self.workers} Ray actor{'s' * (self.workers != 1)} on {on}"
        return "this process" if self.workers == 1 else f"{self.workers} local processes"


class Task(Protocol):
    """What :func:`fan_out` runs (module doc)."""

    def setup(self) -> None: ...

    def __call__(self, item: Any) -> Any: ...


class FanoutError(StudioError):
    """A task failed on one item (the message names it and the error)."""


def fan_out(
    task: Task,
    items: Sequence[Any],
    cfg: FanoutConfig | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    stage: str = "tasks",
    names: Sequence[str] | Callable[[Any], str] | None = None,
    on_result: Callable[[int, Any], Sequence[Any] | None] | None = None,
    total: int | None = None,
) -> dict[int, Any]:
    """``task`` over ``items`` as ``cfg`` says (module doc); ``{index: result}`` of the items finished.
    ``on_result(i, result)`` is called in this process as each item finishes (before its progress report); the
    items it returns (if any) are run too. ``names``: one per item given, or ``name(item)``; ``total``: the
    progress total when follow-ups are expected (default: the items known so far)."""
    cfg = cfg or FanoutConfig()
    work = Work(list(items))
    done: dict[int, Any] = {}

    def name(i: int) -> str | None:
        if callable(names):
            return names(work.items[i])
        return names[i] if names is not None and i < len(names) else None

    def finished(i: int, result: Any) -> None:
        done[i] = result
        more = on_result(i, result) if on_result is not None else None
        work.items.extend(more or ())
        report(progress, stage, len(done), max(total or 0, len(work.items)), item=name(i))

    report(progress, stage, 0, max(total or 0, len(work.items)))
    if not work.items or stopped(cancel):
        return done

    def failed(items: Sequence[Any], i: int, e: BaseException) -> FanoutError:
        if isinstance(e, SetupFailed):  # every item of that worker would say it: said once, as the workers'
            return FanoutError(f"a worker could not start: {e}")
        return FanoutError(f"item {i} ({name(i) or str(items[i])[:80]}) failed: {type(e).__name__}: {e}")

    width = min(cfg.workers, len(work.items))  # no more workers than items (a follow-up takes its item's place)
    if cfg.ray:
        from studio.learn.ray_cluster import run_on_ray

        run_on_ray(_Kept(task), work.items, work.take, replace(cfg, workers=width), finished, cancel, failed)
    elif cfg.workers == 1:
        _in_process(task, work, finished, cancel)
    else:
        _on_processes(_Kept(task), work, width, finished, cancel, failed)
    return done


class SetupFailed(StudioError):
    """A worker could not set its task up (a model or data it loads): raised for each item it is handed."""


class _Kept:
    """A task as a worker holds it: an error in its ``setup()`` is kept and raised (as :class:`SetupFailed`, its
    message) for each item, so the driver says it in one line instead of a broken pool's traceback per worker."""

    def __init__(self, task: Task):
        self.task, self.error = task, None

    def setup(self) -> None:
        try:
            self.task.setup()
        except Exception as e:
            self.error = SetupFailed(f"{type(e).__name__}: {e}")

    def __call__(self, item: Any) -> Any:
        if self.error is not None:
            raise self.error
        return self.task(item)


class Work:
    """The items of a fan-out, handed out in order; it grows while it runs (follow-ups, module doc)."""

    def __init__(self, items: list[Any]):
        self.items, self._next = items, 0

    def take(self) -> int | None:
        """The next item's index, None when every item known so far is handed out."""
        if self._next >= len(self.items):
            return None
        self._next += 1
        return self._next - 1


def _in_process(task: Task, work: Work, finished: Callable, cancel: threading.Event | None) -> None:
    task.setup()
    try:
        while not stopped(cancel) and (i := work.take()) is not None:
            finished(i, task(work.items[i]))
    finally:
        close = getattr(task, "close", None)
        if close is not None:
            close()


_WORKER_TASK: _Kept | None = None  # the task a worker process set up (one per process)


def _set_up(task: _Kept) -> None:
    global _WORKER_TASK
    task.setup()
    _WORKER_TASK = task


def _run_one(item: Any) -> Any:
    assert _WORKER_TASK is not None, "a worker process ran an item before its task was set up"
    return _WORKER_TASK(item)


def _on_processes(
    task: _Kept, work: Work, workers: int, finished: Callable, cancel: threading.Event | None, failed: Callable
) -> None:
    """At most ``2 × workers`` items in flight (a short queue: a cancel leaves little unstarted work behind) on
    ``workers`` spawned processes, each process set up once."""
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_set_up, initargs=(task,))
    flying: dict[Future, int] = {}
    ok = False  # False when it ends by an error or a cancel: the workers are ended, not waited for

    def top_up() -> None:
        while len(flying) < 2 * workers and (i := work.take()) is not None:
            flying[pool.submit(_run_one, work.items[i])] = i

    try:
        top_up()
        while flying:
            ready, _ = wait(flying, timeout=POLL_S, return_when=FIRST_COMPLETED)
            if stopped(cancel):
                break
            for f in ready:
                i = flying.pop(f)
                try:
                    result = f.result()
                except Exception as e:
                    raise failed(work.items, i, e) from e
                finished(i, result)
            top_up()
        ok = not stopped(cancel)
    finally:
        for f in flying:
            f.cancel()
        processes = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=ok, cancel_futures=True)
        if not ok:
            for p in processes:  # running items stop now, not at their end (a shard is written atomically)
                p.terminate()
