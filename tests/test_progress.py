"""studio.cli.progress: a bar per engine stage (none with --quiet), a bar over items, and Ctrl-C → cancel (the first
sets the event, the second stops at once), driven by real signals."""

from __future__ import annotations

import os
import signal
import time

import pytest

from studio.cli.progress import CountBar, StageBars, ctrl_c_cancels


def _ctrl_c() -> None:
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.05)  # the handler runs at the next bytecode boundary of the main thread


def test_first_ctrl_c_sets_cancel_second_interrupts_and_the_handler_is_restored():
    before = signal.getsignal(signal.SIGINT)
    with ctrl_c_cancels() as cancel:
        assert not cancel.is_set()
        _ctrl_c()
        assert cancel.is_set()
        with pytest.raises(KeyboardInterrupt):
            _ctrl_c()
    assert signal.getsignal(signal.SIGINT) is before


def test_a_bar_per_stage_with_the_best_loss(capsys):
    with StageBars(quiet=False) as bars:
        bars("search", 1, 4, 0.5)
        bars("search", 4, 4, 0.25)
        first = bars.bar
        bars("refine", 2, 2, float("nan"))  # a new stage: the search bar closes, a refine bar opens
        assert bars.bar is not first and bars.stage == "refine"
    assert bars.bar is None  # closed on the way out
    err = capsys.readouterr().err
    assert "search: 100%" in err and "4/4" in err and "best=0.2500" in err
    assert "refine: 100%" in err and "best=nan" not in err


def test_quiet_draws_nothing(capsys):
    with StageBars(quiet=True) as bars:
        bars("search", 1, 4, 0.5)
    with CountBar(2, "evaluate", "target", quiet=True) as count:
        count(1, 2, "a.png")
    assert capsys.readouterr().err == ""


def test_count_bar_follows_done_and_names_the_last_item(capsys):
    with CountBar(3, "evaluate", "target", quiet=False) as count:
        count(1, 3, "a.png")
        count(2, 3, "b.png")
    assert count.bar.n == 2
    err = capsys.readouterr().err
    assert "evaluate:" in err and "2/3" in err and "b.png" in err
