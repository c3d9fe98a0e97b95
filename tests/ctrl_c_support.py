"""Ctrl-C sent to this test process at a chosen moment of a verb run in it (the verb's own handler takes it)."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path


@contextlib.contextmanager
def ctrl_c_once_written(path: Path) -> Iterator[None]:
    """Within the block, send SIGINT to this process once, as soon as ``path`` exists (e.g. a training run's first
    checkpoint); nothing is sent after the block. The block must run in the main thread, where a verb sets its
    Ctrl-C handler, and must still be inside that verb when ``path`` appears."""
    assert threading.current_thread() is threading.main_thread(), "signal handlers are set in the main thread only"
    ended = threading.Event()

    def watch() -> None:
        while not ended.is_set():
            if path.exists():
                os.kill(os.getpid(), signal.SIGINT)  # handled in the main thread, by the verb
                return
            time.sleep(0.01)

    watcher = threading.Thread(target=watch, name="ctrl-c", daemon=True)
    watcher.start()
    try:
        yield
    finally:
        ended.set()
        watcher.join()
