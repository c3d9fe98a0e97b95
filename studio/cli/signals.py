"""Stop signals for the verbs that hold something: SIGTERM and SIGHUP end them the way Ctrl-C does.

Python's defaults kill a process on SIGTERM or SIGHUP at once: no ``finally`` runs, so a player would send no stop,
write no log and say nothing, and ``lab`` would leave its JupyterLab server running. :func:`stop_on_signals` installs
handlers (main thread only; restored afterwards) that raise :class:`Signalled`, a ``KeyboardInterrupt``, so every
path that already ends safely on Ctrl-C (the player's stop, the session's close, the log, ``lab``'s shutdown) runs
for these signals too. SIGINT is handled the same way even where the shell started the process with it ignored
(``shadow-studio lab &`` in a script). SIGHUP ignored on entry (``nohup``) stays ignored.

Only the first signal raises: later ones (a second Ctrl-C, a supervisor's repeated SIGTERM) are ignored until the
verb returns, so the stop, the torque policy and the log are not cut short. The exit code is the shell's for the
signal that ended the verb: 128 + its number (Ctrl-C 130, SIGHUP 129, SIGTERM 143), see :func:`exit_code`.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator

STOP_SIGNALS = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name)
)  # SIGHUP: POSIX only


_HOLD = {"after_stop": False}  # set by hold_after_stop(): this process exits once a stop signal ended its verb


def hold_after_stop() -> None:
    """This process ends with the verb: once a stop signal was caught, later ones stay ignored until it exits."""
    _HOLD["after_stop"] = True


class Signalled(KeyboardInterrupt):
    """A stop signal, raised in the main thread; ``str()`` names it as a person knows it ("Ctrl-C", "SIGTERM")."""

    def __init__(self, signum: int):
        self.signum = signum
        name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
        super().__init__(name)

    @property
    def exit_code(self) -> int:
        """128 + the signal's number, as a shell reports a process that a signal ended."""
        return 128 + self.signum


def exit_code(stop: BaseException | None) -> int:
    """The exit code for a verb that ``stop`` ended (a :class:`Signalled` or a plain Ctrl-C: 130)."""
    return stop.exit_code if isinstance(stop, Signalled) else 130


@contextlib.contextmanager
def stop_on_signals(verb: str) -> Iterator[list[Signalled]]:
    """For the ``with`` block: SIGINT, SIGTERM and SIGHUP raise :class:`Signalled` (once); yields a list that then
    holds it, so a verb that caught the stop (the player turns it into a result) still knows which signal it was.
    ``verb`` names the verb in the line printed when a later signal is ignored. Off the main thread it does
    nothing (signal handlers can only be set there)."""
    caught: list[Signalled] = []
    if threading.current_thread() is not threading.main_thread():
        yield caught
        return

    def on_signal(signum: int, frame) -> None:
        if caught:  # already stopping: let the stop, the torque policy and the log finish
            with contextlib.suppress(OSError):  # os.write: print() here could re-enter a write in progress
                os.write(sys.stderr.fileno(), f"shadow-studio {verb}: already stopping, please wait\n".encode())
            return
        caught.append(Signalled(signum))
        raise caught[0]

    previous = {}
    for sig in STOP_SIGNALS:
        if sig != signal.SIGINT and signal.getsignal(sig) is signal.SIG_IGN:
            continue  # nohup's SIGHUP (or a supervisor's choice) stays ignored
        previous[sig] = signal.signal(sig, on_signal)
    try:
        yield caught
    finally:
        for sig, handler in previous.items():
            if caught and _HOLD["after_stop"]:  # the process exits with the first signal's code
                handler = signal.SIG_IGN
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
