"""Where the studio keeps the user's things: the user folder (demo project, the lab's notebook) and the cache.

``$SHADOW_STUDIO_HOME`` moves the user folder and ``$SHADOW_STUDIO_CACHE`` the cache (built indexes, reusable by
every project and process); both default to ``~/.cache/shadow-studio``.

One process fills a cache entry at a time (the retrieval index, the compiled kernels): :func:`cache_lock` is an
advisory ``fcntl.flock`` on a lock file beside what is built. The first process takes it and builds; any other one
waits (``on_wait`` once, e.g. a log line and a progress event), then takes it and should find the work done. The
kernel releases a lock when its holder exits for any reason, so a killed build leaves no stale lock. Locks are per
open file, so two threads of one process exclude each other too. A lock file that cannot be made (a read-only cache)
means no lock: the work is done without one. The lock file is left in place (removing it could let two processes
hold locks on two files of one name).
"""

from __future__ import annotations

import contextlib
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from studio.errors import stopped

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no POSIX locks; two processes may then both build
    fcntl = None  # type: ignore[assignment]

log = logging.getLogger(__name__)
HOME_ENV = "SHADOW_STUDIO_HOME"  # environment variable: the user folder for the demo project and the lab's notebook
CACHE_ENV = "SHADOW_STUDIO_CACHE"  # environment variable: the folder of rebuildable caches (retrieval indexes)
DEFAULT = Path("~/.cache/shadow-studio")
LOCK_POLL_S = 0.2  # how often a process waiting for a cache lock looks at it and at its cancel, s


def studio_home() -> Path:
    """The user folder of the studio: ``$SHADOW_STUDIO_HOME``, else ``~/.cache/shadow-studio``."""
    return Path(os.environ.get(HOME_ENV) or DEFAULT).expanduser()


def cache_dir() -> Path:
    """The folder of rebuildable caches: ``$SHADOW_STUDIO_CACHE``, else ``~/.cache/shadow-studio``."""
    return Path(os.environ.get(CACHE_ENV) or DEFAULT).expanduser()


@contextlib.contextmanager
def cache_lock(
    lock: Path, cancel: threading.Event | None = None, on_wait: Callable[[], None] | None = None
) -> Iterator[bool]:
    """Hold the lock file ``lock`` (module doc: one process fills a cache entry at a time): True once held, or at
    once when no lock can be made; False when ``cancel`` was set while another process held it. ``on_wait()`` is
    called once, when this process has to wait."""
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
            time.sleep(LOCK_POLL_S)
