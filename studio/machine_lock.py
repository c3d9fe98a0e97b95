"""Work done once per machine: an advisory lock that other processes wait for, then find the work done.

A build that every process of this machine shares (the retrieval index, the compiled kernels) is done under
:func:`held`: an ``fcntl.flock`` on a lock file beside what it builds. The first process takes it and builds; any
other one waits (``on_wait`` once, e.g. a log line and a progress event), then takes it and should find the work
done. The kernel releases a lock when its holder exits for any reason, so a killed build leaves no stale lock. Locks
are per open file, so two threads of one process exclude each other too. A lock file that cannot be made (a
read-only cache) means no lock: the work is done without one. The lock file is left in place (removing it could let
two processes hold locks on two files of one name).
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from studio.errors import stopped

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no POSIX locks; two processes may then both build
    fcntl = None  # type: ignore[assignment]

__all__ = ["POLL_S", "held"]

log = logging.getLogger(__name__)
POLL_S = 0.2  # how often a waiting process looks at the lock and at its cancel, s


@contextlib.contextmanager
def held(
    lock: Path, cancel: threading.Event | None = None, on_wait: Callable[[], None] | None = None
) -> Iterator[bool]:
    """Hold the lock file ``lock`` (module doc): True once held, or at once when no lock can be made; False when
    ``cancel`` was set while another process held it. ``on_wait()`` is called once, when this process has to wait."""
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        f = open(lock, "a")  # noqa: SIM115 - held open for the lock's lifetime, closed below
    except OSError as exc:
        log.debug("no lock at %s (%s): working without one", lock, exc)
        yield True
        return
    try:
        yield fcntl is None or _take(f, cancel, on_wait)
    finally:
        f.close()  # releases the lock


def _take(f, cancel: threading.Event | None, on_wait: Callable[[], None] | None) -> bool:
    """Lock the open file ``f``: at once, or once its holder lets go (``on_wait()`` first); False when ``cancel``
    is set first."""
    waited = False
    while True:
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if not waited and on_wait is not None:
                on_wait()
            waited = True
            if stopped(cancel):
                return False
            time.sleep(POLL_S)
