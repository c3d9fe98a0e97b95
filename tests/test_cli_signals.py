"""studio.cli.signals with real signals sent to this process: SIGTERM, SIGHUP and Ctrl-C raise one ``Signalled``
(a ``KeyboardInterrupt``) naming them, later ones are ignored until the block ends, handlers are restored, SIGINT is
handled even where it was ignored (a background job) and an ignored SIGHUP (nohup) stays ignored."""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from studio.cli.signals import Signalled, exit_code, stop_on_signals


def send(sig: int) -> None:
    if threading.current_thread() is not threading.main_thread():  # no handlers there: the signal would kill us
        pytest.skip("signal handlers can only be set in the main thread, where this test does not run")
    os.kill(os.getpid(), sig)
    time.sleep(0.05)  # the handler runs in the main thread at its next bytecode


@pytest.mark.parametrize("sig, name, code", [(signal.SIGTERM, "SIGTERM", 143), (signal.SIGHUP, "SIGHUP", 129),
                                             (signal.SIGINT, "Ctrl-C", 130)])  # fmt: skip
def test_a_stop_signal_raises_once_and_the_handlers_come_back(sig, name, code):
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    with stop_on_signals("test") as caught:
        with pytest.raises(KeyboardInterrupt) as info:
            send(sig)
        assert isinstance(info.value, Signalled) and str(info.value) == name and exit_code(info.value) == code
        assert caught == [info.value]
        send(sig)  # a second one while the verb cleans up: ignored
        send(signal.SIGTERM)
    assert {s: signal.getsignal(s) for s in before} == before
    assert exit_code(KeyboardInterrupt()) == 130


def test_sigint_is_handled_where_it_was_ignored_and_an_ignored_sighup_stays_ignored():
    old_int, old_hup = signal.signal(signal.SIGINT, signal.SIG_IGN), signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        with stop_on_signals("test"):
            send(signal.SIGHUP)  # nohup: nothing happens
            with pytest.raises(Signalled, match="Ctrl-C"):
                send(signal.SIGINT)  # `lab &` in a script: Ctrl-C's signal still stops it
        assert signal.getsignal(signal.SIGINT) is signal.SIG_IGN and signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGHUP, old_hup)


def test_in_the_commands_own_process_a_stop_leaves_the_stop_signals_ignored_until_it_exits(monkeypatch):
    """A second Ctrl-C just after the verb ended must not kill the exiting process (exit code 130, not -2):
    Python's finalization resets Python handlers to the default action but leaves ignored signals ignored."""
    import studio.cli.signals as signals

    monkeypatch.setitem(signals._HOLD, "after_stop", True)
    before = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        with stop_on_signals("test"):
            pass  # no signal: the handlers come back
        assert {s: signal.getsignal(s) for s in before} == before
        with pytest.raises(Signalled), stop_on_signals("test"):
            send(signal.SIGINT)
        assert all(signal.getsignal(s) is signal.SIG_IGN for s in before)
    finally:
        for s, handler in before.items():
            signal.signal(s, handler)
