"""One writer at a time: the project folder's lock, and the check that nobody else saved since we read.

A project is written by one process at a time (DESIGN §4 "The studio's state"). The lock is an advisory
``fcntl.flock`` on ``NAME.shadow/.lock``: the kernel releases it when its holder exits for any reason (a
``kill -9`` included), so a stale lock is never left behind: the next writer simply takes it, and the note of who held
it before (pid, host, what, since when; JSON in the file) is overwritten. ``flock`` locks are per open file, so two
``Project`` objects on one folder in one process exclude each other too.

Two ways to hold it:

- **For a save** (every edit, undo, redo, a job's result): taken for the save alone, waiting up to
  :data:`SAVE_WAIT_S` for another short save; when a long writer holds it the edit is refused at once with who holds
  it (:class:`ProjectLocked`), nothing changed.
- **For a run** (:meth:`WriterLock.hold`, ``project run``, the notebook's Run): held from before the first job to
  after the last save, so a second run refuses (or waits, ``wait``) before it computes anything.

The lock alone cannot stop a lost update: a notebook opened the project, a terminal run then saved new results and
exited, and the notebook's next edit would save its older state over them. So every save first compares
``project.json`` on disk with the stamp (sha256) of what this object last read or wrote, and refuses with
:class:`ProjectChanged` when another process saved in between (reopen the project to see its work; nothing of
either is lost).
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import socket
import threading
import time
from collections.abc import Iterator
from datetime import datetime, timezone
from pathlib import Path

from studio.project.state import ProjectError

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows: no POSIX locks (the studio's hardware side is POSIX too)
    fcntl = None  # type: ignore[assignment]

LOCK = ".lock"  # the lock file inside a project folder
SAVE_WAIT_S = 3.0  # how long a save waits for another process's save before it gives up
_POLL_S = 0.05  # how often a waiting writer tries again


class ProjectLocked(ProjectError):
    """Another process (or another open copy of the project) is writing it now; ``holder`` says who."""

    def __init__(self, message: str, holder: dict):
        super().__init__(message)
        self.holder = holder  # {"pid", "host", "what", "since"} of the writer, as far as it is known


class ProjectChanged(ProjectError):
    """The project was saved by another process since it was opened here: reopen it (nothing was saved)."""


def stamp(folder: Path) -> str:
    """sha256 of ``folder``'s ``project.json`` as it is on disk now ("" when there is none)."""
    from studio.project.project_format import DOC

    try:
        return hashlib.sha256((Path(folder) / DOC).read_bytes()).hexdigest()
    except (FileNotFoundError, NotADirectoryError):  # (a file given as the folder: read_doc says so)
        return ""


def _describe(holder: dict) -> str:
    what = holder.get("what") or "a save"
    who = f"pid {holder['pid']}" if holder.get("pid") else "another process"
    host = f" on {holder['host']}" if holder.get("host") else ""
    since = f", since {holder['since']}" if holder.get("since") else ""
    return f"{what} ({who}{host}{since})"


class WriterLock:
    """The write lock of one project folder (module doc); reentrant within one object and thread-safe."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self._fd: int | None = None
        self._depth = 0
        self._mutex = threading.RLock()

    @property
    def held(self) -> bool:
        """Whether this object holds the lock now."""
        return self._fd is not None

    def _holder(self) -> dict:
        try:
            with open(self.folder / LOCK, encoding="utf-8") as f:
                d = json.loads(f.read(4096) or "{}")
            return d if isinstance(d, dict) else {}
        except (OSError, ValueError):
            return {}

    def _try(self, what: str) -> bool:
        if fcntl is None:
            self._fd = -1
            return True
        flags = os.O_RDWR | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
        try:
            fd = os.open(self.folder / LOCK, flags, 0o644)
        except OSError as e:
            lock = self.folder / LOCK
            raise ProjectError(f"cannot lock the project {self.folder} for writing ({e.strerror}): {lock}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return False
        note = {"pid": os.getpid(), "host": socket.gethostname(), "what": what,
                "since": datetime.now(timezone.utc).isoformat(timespec="seconds")}  # fmt: skip
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps(note).encode(), 0)
        except OSError:  # a full disk: the lock holds all the same, only the note of who holds it is missing
            pass
        self._fd = fd
        return True

    def acquire(self, what: str = "", wait: float = 0.0) -> None:
        """Take the lock (again, if this object holds it), trying for up to ``wait`` seconds; ``what`` names the
        writer for whoever is refused ("project run"). A :class:`ProjectLocked` when another writer keeps it."""
        with self._mutex:
            if self._fd is not None:
                self._depth += 1
                return
            deadline = time.monotonic() + max(0.0, wait)
            while not self._try(what):
                holder = self._holder()
                long_writer = holder.get("what") not in (None, "", "a save")  # a run: no point in waiting for a save
                if time.monotonic() >= deadline or (long_writer and what == "a save"):
                    raise ProjectLocked(
                        f"the project {self.folder} is being written by {_describe(holder)}; wait until it "
                        "finishes (or stop it there), then try again. Nothing was changed here", holder,
                    )  # fmt: skip
                time.sleep(_POLL_S)
            self._depth = 1

    def release(self) -> None:
        """Give the lock back (after the outermost :meth:`acquire`)."""
        with self._mutex:
            if self._fd is None:
                return
            self._depth -= 1
            if self._depth > 0:
                return
            fd, self._fd = self._fd, None
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.ftruncate(fd, 0)  # nobody holds it now
                os.close(fd)  # closing the file releases the flock

    @contextlib.contextmanager
    def hold(self, what: str, wait: float = 0.0) -> Iterator[None]:
        """``with lock.hold("project run"):`` the lock for a whole run (module doc)."""
        self.acquire(what, wait)
        try:
            yield
        finally:
            self.release()

    def for_save(self) -> contextlib.AbstractContextManager[None]:
        """The lock for one save: this object's own hold if it has one, else taken for the save alone."""
        return self.hold("a save", SAVE_WAIT_S)
