"""Where a job's engine call runs: a thread of this process, or a spawned worker process.

Both speak one message protocol to the queue's dispatcher thread (plain tuples)::

    ("progress", stage, step, total, best, shadow, item)     any number, in order
    ("done", result) | ("cancelled",) | ("error", type, message, traceback)     exactly one, last

A job's ``run(report, cancel)`` is called in the worker with a :class:`~studio.jobs.events.Reporter` and a
cancel event (``threading.Event``, or a ``multiprocessing`` event in a process: the same ``is_set()``). For a process
worker ``run`` must pickle (a module-level function, or a ``functools.partial`` of one with picklable arguments) and its
result must pickle; the process is spawned once (fresh interpreter: torch, the model and numba's caches load on its
first job) and reused, and killed when a cancelled job does not return within the grace time. Spawning re-imports a
script's main module in the worker: a script using it keeps its work under ``if __name__ == "__main__":``
(notebooks need nothing).

``threads`` sets torch's CPU threads where the engine runs (:data:`studio.learn.threads.DEFAULT_THREADS` unless
given); a thread worker sets it for the job's duration only (torch's setting is per process) and restores it.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import pickle
import queue
import signal
import threading
import traceback
from collections.abc import Callable
from typing import Any

from studio.errors import Cancelled
from studio.jobs.events import Reporter, Send
from studio.learn.threads import DEFAULT_THREADS, torch_threads

log = logging.getLogger(__name__)

Run = Callable[[Reporter, Any], Any]  # run(report, cancel) -> result


def execute(run: Run, send: Send, cancel, threads: int | None, pickle_result: bool = False) -> None:
    """Call ``run(report, cancel)`` and send exactly one final message (module doc)."""
    try:
        with torch_threads(threads):
            result = run(Reporter(send, cancel), cancel)
        if pickle_result:
            result = pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL)
    except Cancelled:  # JobCancelled, or the engine's own (a cancelled plan): the job ends cancelled
        send(("cancelled",))
    except BaseException as e:  # SystemExit from engine code too: the job fails, the worker lives on
        send(("error", type(e).__name__, str(e), traceback.format_exc()))
    else:
        send(("done", result))


class ThreadRunner:
    """One job running in a daemon thread of this process."""

    def __init__(self, run: Run, threads: int | None, name: str):
        self._messages: queue.Queue = queue.Queue()
        self.cancel_event = threading.Event()
        self._thread = threading.Thread(
            target=execute, args=(run, self._messages.put, self.cancel_event, threads), name=name, daemon=True
        )
        self._thread.start()

    def get(self, timeout: float) -> tuple | None:
        """The next message, or None after ``timeout`` s without one."""
        try:
            return self._messages.get(timeout=timeout)
        except queue.Empty:
            return None

    def cancel(self) -> None:
        self.cancel_event.set()

    def alive(self) -> bool:
        return True  # a thread that ends always sends its final message first

    def abandon(self) -> None:
        """Stop waiting for it: a thread cannot be killed, so it runs on to its next cancel check, result ignored."""
        log.warning("job thread %s did not stop within the grace time; its result will be ignored", self._thread.name)

    def join(self, timeout: float | None = None) -> bool:
        self._thread.join(timeout)
        return not self._thread.is_alive()


class ThreadWorker:
    """Jobs run in a thread of this process (cheap to start; the model and caches are shared)."""

    name = "thread"

    def __init__(self, threads: int | None = DEFAULT_THREADS):
        self.threads = threads
        self._count = 0

    def check(self, run: Run) -> None:
        """Anything callable runs in a thread."""
        if not callable(run):
            raise TypeError(f"a job's run must be callable run(report, cancel), not {type(run).__name__}")

    def start(self, run: Run) -> ThreadRunner:
        self._count += 1
        return ThreadRunner(run, self.threads, f"studio-job-{self._count}")

    def close(self) -> None:
        pass


def _serve(tasks, out, cancel, threads: int | None) -> None:
    """The worker process's loop: one pickled ``run`` at a time until None. Ctrl-C is the parent's to handle (it
    cancels the job), so the worker ignores SIGINT."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    while True:
        payload = tasks.get()
        if payload is None:
            return
        try:
            run = pickle.loads(payload)
        except Exception as e:
            out.put(("error", type(e).__name__, f"the job could not be unpickled in the worker: {e}", ""))
            continue
        execute(run, out.put, cancel, threads, pickle_result=True)


class ProcessRunner:
    """One job running in the worker's process."""

    def __init__(self, worker: ProcessWorker, payload: bytes):
        self.worker = worker
        self.proc, self._out, self.cancel_event = worker._proc, worker._out, worker._cancel
        self.cancel_event.clear()
        worker._tasks.put(payload)

    def get(self, timeout: float) -> tuple | None:
        try:
            msg = self._out.get(timeout=timeout)
        except queue.Empty:
            return None
        if msg[0] == "done":
            try:
                return ("done", pickle.loads(msg[1]))
            except Exception as e:
                return ("error", type(e).__name__, f"the job's result could not be read back: {e}", "")
        return msg

    def cancel(self) -> None:
        self.cancel_event.set()

    def alive(self) -> bool:
        return self.proc.is_alive()

    def abandon(self) -> None:
        """Kill the worker process (a fresh one starts with the next job)."""
        log.warning("worker process %s did not stop within the grace time: killing it", self.proc.pid)
        self.worker.kill()

    def join(self, timeout: float | None = None) -> bool:
        return True


class ProcessWorker:
    """Jobs run in one spawned worker process, reused from job to job (module doc)."""

    name = "process"

    def __init__(self, threads: int | None = DEFAULT_THREADS):
        self.threads = threads
        self._ctx = mp.get_context("spawn")
        self._proc = None

    def check(self, run: Run) -> None:
        """A process worker needs ``run`` to pickle: raise TypeError saying so (at submit, not in the worker)."""
        try:
            pickle.dumps(run, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as e:
            raise TypeError(
                f"a process worker needs a picklable job (a module-level function or functools.partial of one): {e}"
            ) from None

    def _ensure(self) -> None:
        if self._proc is not None and self._proc.is_alive():
            return
        ctx = self._ctx
        self._tasks, self._out, self._cancel = ctx.Queue(), ctx.Queue(), ctx.Event()
        self._proc = ctx.Process(
            target=_serve, args=(self._tasks, self._out, self._cancel, self.threads), name="studio-jobs", daemon=True
        )
        self._proc.start()

    def start(self, run: Run) -> ProcessRunner:
        payload = pickle.dumps(run, protocol=pickle.HIGHEST_PROTOCOL)
        self._ensure()
        return ProcessRunner(self, payload)

    def kill(self) -> None:
        """End the worker process now (its queues are dropped with it)."""
        if self._proc is None:
            return
        self._proc.kill()
        self._proc.join(2.0)
        for q in (self._tasks, self._out):
            q.cancel_join_thread()
            q.close()
        self._proc = None

    def close(self) -> None:
        """Ask the worker process to exit; kill it if it does not within 2 s."""
        if self._proc is None:
            return
        if self._proc.is_alive():
            self._tasks.put(None)
            self._proc.join(2.0)
        if self._proc is not None and self._proc.is_alive():
            self.kill()
        else:
            self._proc = None


WORKERS = {"thread": ThreadWorker, "process": ProcessWorker}
