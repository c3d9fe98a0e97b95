"""What a long verb shows while the engine works, and how Ctrl-C stops it (DESIGN §5.11: the engine takes a progress
callback and a cancel event; this is the command line's side of both).

- :class:`StageBars`: one tqdm bar per stage on stderr, fed by the engine's ``progress(stage, step, total[, best])``
  callbacks; each bar closes when the next stage starts. :class:`CountBar`: one bar over items (targets,
  sequences, runs) fed by ``progress(done, total, name)``. ``--quiet`` (:func:`add_quiet_flag`) shows neither.
- :func:`ctrl_c_cancels`: the first Ctrl-C sets the cancel event (the engine returns what it finished, the verb
  writes it and exits 130); a second one raises ``KeyboardInterrupt`` and stops at once.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import threading
from abc import ABC, abstractmethod
from collections.abc import Iterator


def add_quiet_flag(parser: argparse.ArgumentParser, help: str = "no progress bars") -> None:
    """``--quiet``: no progress bars (``help`` says what else the verb leaves out)."""
    parser.add_argument("--quiet", action="store_true", help=help)


class _Closes(ABC):
    """``with bars:`` closes them on the way out, whatever raised."""

    @abstractmethod
    def close(self) -> None:
        """Close every bar (idempotent)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class StageBars(_Closes):
    """One tqdm bar per stage on stderr, each closed when the next stage starts; nothing when ``quiet``.

    Call it as the engine's ``progress(stage, step, total, best=None)``: ``step`` of ``total`` done in ``stage``,
    ``best`` (the best loss so far, when finite) shown after the bar. ``leave=False`` clears each finished bar (under
    a :class:`CountBar` of runs). Close it (or use it as a context manager) before printing a line of your own."""

    def __init__(self, quiet: bool, leave: bool = True):
        self.quiet, self.leave = quiet, leave
        self.bar, self.stage = None, None

    def __call__(self, stage: str, step: int, total: int, best: float | None = None) -> None:
        if self.quiet:
            return
        from tqdm import tqdm

        if stage != self.stage:
            self.close()
            self.bar = tqdm(total=total, desc=stage, unit="step", leave=self.leave, file=sys.stderr)
            self.stage = stage
        self.bar.update(step - self.bar.n)
        if best is not None and math.isfinite(best):
            self.bar.set_postfix(best=f"{best:.4f}", refresh=False)

    def close(self) -> None:
        """Close the open bar (if any); the next call starts a new one."""
        if self.bar is not None:
            self.bar.close()
        self.bar, self.stage = None, None


class CountBar(_Closes):
    """One tqdm bar over ``total`` items on stderr (nothing when ``quiet``), fed by ``progress(done, total, name)``:
    ``done`` items finished, the last one ``name`` (shown after the bar)."""

    def __init__(self, total: int, desc: str, unit: str, quiet: bool):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=desc, unit=unit, disable=quiet, file=sys.stderr)

    def __call__(self, done: int, total: int, name: str) -> None:
        self.bar.update(done - self.bar.n)
        self.bar.set_postfix_str(name)

    def close(self) -> None:
        self.bar.close()


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
