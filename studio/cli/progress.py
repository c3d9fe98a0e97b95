"""What a long verb shows while the engine works, and how Ctrl-C stops it (DESIGN §5.11: the engine takes a progress
callback and a cancel event; this is the command line's side of both).

- The bars: :class:`studio.jobs.bars.TqdmBars`, the one tqdm face of the engine's
  :class:`~studio.errors.Progress` events and of job events; :func:`add_quiet_flag` adds ``--quiet``
  (``TqdmBars(disable=args.quiet)`` then draws nothing).
- :func:`ctrl_c_cancels`: the first Ctrl-C sets the cancel event (the engine returns what it finished, the verb
  writes it and exits 130); a second one raises ``KeyboardInterrupt`` and stops at once.
"""

from __future__ import annotations

import argparse
import contextlib
import signal
import threading
from collections.abc import Iterator


def add_quiet_flag(parser: argparse.ArgumentParser, help: str = "no progress bars") -> None:
    """``--quiet``: no progress bars (``help`` says what else the verb leaves out)."""
    parser.add_argument("--quiet", action="store_true", help=help)


@contextlib.contextmanager
def ctrl_c_cancels() -> Iterator[threading.Event]:
    """An event that the first Ctrl-C sets (a second one raises ``KeyboardInterrupt`` as usual).

    Off the main thread (where signal handlers cannot be set) the event is only the caller's to set."""
    cancel = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield cancel
        return

    def on_sigint(signum, frame) -> None:
        cancel.set()
        signal.signal(signal.SIGINT, signal.default_int_handler)

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield cancel
    finally:
        signal.signal(signal.SIGINT, previous)
