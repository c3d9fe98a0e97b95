"""The e-stop latch across processes (hardware.estop): set by one bus, one verb or one process, refused by every
other until one explicit reset, wherever it is made. Real pyserial against the emulator on a pseudo-terminal; the
latch file is this test's own (conftest's ``estop_file``: ``$SHADOW_STUDIO_ESTOP``, inherited by subprocesses)."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from hardware import estop
from hardware.calibration import default_calibration
from hardware.emulator import ServoEmulator
from hardware.errors import EStopLatched, EStopResetFailed
from hardware.jog import Jog
from hardware.serial_bus import BusConfig, SerialServoBus
from hardware.session import ServoSession
from studio.cli.main import main


def env() -> dict[str, str]:
    """The environment of a subprocess: this test's (its own e-stop latch file, conftest), unbuffered output."""
    return {**os.environ, "PYTHONUNBUFFERED": "1"}


def tiny_show(hand, path, seconds=0.5):
    from studio.motion.show import Show, save_show

    t = np.arange(0, seconds, 1 / 40)
    q = np.tile(hand.rest_pose(), (len(t), 1))
    q[:, 0] = 0.3 * np.sin(t)
    save_show(Show.from_samples(hand, t, q, title="tiny"), path)
    return path


def test_the_latch_file(estop_file):
    assert estop.latch_path() == estop_file and not estop.is_latched() and estop.read_latch() is None
    first = estop.set_latch("jog on servo bus '/dev/ttyUSB0'")
    assert estop.is_latched() and first.pid == os.getpid() and "jog on servo bus" in first.describe()
    assert json.loads(estop_file.read_text())["by"] == "jog on servo bus '/dev/ttyUSB0'"
    assert estop.set_latch("the player") == first  # the first cause is kept
    with pytest.raises(EStopLatched, match=r"the e-stop is latched \(set by jog on servo bus .* at .*\): no servo"):
        estop.check_not_latched()
    assert estop.clear_latch() == first and not estop.is_latched() and estop.clear_latch() is None
    estop_file.write_text("{not json")  # a damaged latch still latches: only a reset removes it
    assert estop.is_latched() and "damaged" in estop.read_latch().by
    assert "damaged" in estop.latched_message("the emulator")
    estop.clear_latch()
    estop.check_not_latched()


def test_an_estop_on_one_bus_holds_on_every_bus_until_one_reset(hand):
    cal = default_calibration(hand)
    with (
        ServoEmulator(cal.ids) as emu_a,
        ServoEmulator(cal.ids) as emu_b,
        SerialServoBus(BusConfig(emu_a.port, timeout_s=0.05)) as a,
        SerialServoBus(BusConfig(emu_b.port, timeout_s=0.05)) as b,
    ):
        assert a.write_positions({1: 600}, 0.0) and b.write_positions({1: 600}, 0.0)
        assert Jog(a, cal).estop()
        assert a.estop_latched and b.estop_latched  # b never pressed anything: the file says so
        with pytest.raises(EStopLatched, match=r"set by jog on servo bus '/dev/pts/\d+'") as info:
            b.move_batch({1: 400}, 0.0)
        assert "no servo moves until it is reset" in str(info.value)
        b.read_position(1)
        assert emu_b.servo(1).last_move == (600, 0)  # nothing went out
        b.reset_estop()  # the reset made on another bus (or process) clears the latch for a too
        assert not estop.is_latched() and not a.estop_latched and not b.estop_latched
        assert a.move_batch({1: 400}, 0.0) == {1: 400} and b.move_batch({1: 400}, 0.0) == {1: 400}


def test_a_reset_that_cannot_remove_the_file_says_so_and_keeps_the_latch(hand, tmp_path, monkeypatch):
    with ServoEmulator([1]) as emu, SerialServoBus(BusConfig(emu.port, timeout_s=0.01)) as bus:
        monkeypatch.setenv("SHADOW_STUDIO_ESTOP", str(tmp_path / "latched"))
        (tmp_path / "latched").mkdir()  # a path that unlink() cannot remove
        assert bus.estop_latched
        with pytest.raises(EStopResetFailed, match="could not be reset.*remove that file by hand"):
            bus.reset_estop()
        assert bus.estop_latched


def test_an_open_session_halts_the_servos_when_another_process_latches(hand):
    """The session's watcher: the servos are halted mid-move while this process is busy elsewhere (a terminal
    waiting for its user), as soon as the latch file appears."""
    cal = default_calibration(hand)
    with ServoSession(calibration=cal) as s:
        s.bus.write_positions({i: 900 for i in cal.ids}, 5.0)  # five seconds on the way
        s.bus.read_position(21)
        estop.set_latch("shadow-studio estop")  # as `shadow-studio estop` in another terminal writes it
        deadline = time.monotonic() + 2
        while not s.bus._estop.is_set() and time.monotonic() < deadline:
            time.sleep(0.01)
        assert s.bus.estop_latched
        s.bus.read_position(21)  # answered after the stop was handled
        before = s.emulator.positions()
        time.sleep(0.15)
        assert s.emulator.positions() == before and all(before[i] < 900 for i in cal.ids)  # halted part-way
        with pytest.raises(EStopLatched, match="set by shadow-studio estop"):
            s.bus.move_batch({1: 500}, 0.0)


def test_jog_stop_quit_then_play_is_refused_until_estop_reset(hand, tmp_path, capsys, monkeypatch):
    """The issue's sequence: `jog`, `stop`, `quit`, then `play`: refused in one line naming the reset; another
    process sees the latch (`estop --status`); `estop --reset` (another process) lets `play` move the hand."""
    show = tiny_show(hand, tmp_path / "tiny.json")
    with ServoEmulator(range(1, 22)) as emu:
        monkeypatch.setattr(sys, "stdin", io.StringIO("stop\nquit\n"))
        assert main(["jog", "--port", emu.port, "--log", str(tmp_path / "jog.txt")]) == 0
        assert "E-STOP" in capsys.readouterr().out
    assert "> stop" in (tmp_path / "jog.txt").read_text()
    status = [sys.executable, "-m", "studio.cli", "estop", "--status"]
    seen = subprocess.run(status, capture_output=True, text=True, env=env(), timeout=60)
    assert seen.returncode == 1 and "set by jog on servo bus" in seen.stdout, seen

    log = tmp_path / "play.npz"
    assert main(["play", str(show), "--dry-run", "--log", str(log)]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "the e-stop is latched (set by jog" in err
    assert "shadow-studio estop --reset" in err and not log.exists()  # refused before the port was opened

    reset = subprocess.run([*status[:-1], "--reset"], capture_output=True, text=True, env=env(), timeout=60)
    assert reset.returncode == 0 and "e-stop reset" in reset.stdout, reset
    assert main(["play", str(show), "--dry-run", "--log", str(log)]) == 0
    assert "completed" in capsys.readouterr().out and log.exists()


def test_estop_verb_latches_and_jog_says_so_and_resets_it(capsys, monkeypatch, tmp_path):
    assert main(["estop"]) == 0
    assert "E-STOP latched (set by shadow-studio estop" in capsys.readouterr().out
    assert main(["estop", "--status"]) == 1
    with ServoEmulator(range(1, 22)) as emu:
        monkeypatch.setattr(sys, "stdin", io.StringIO("go 10\nreset\ngo 10\nquit\n"))
        assert main(["jog", "--port", emu.port, "--log", str(tmp_path / "jog.txt")]) == 0
    out = capsys.readouterr().out
    assert "? the e-stop is latched (set by shadow-studio estop" in out and "type reset" in out
    assert "(shadow-studio estop --reset clears it; in jog, type reset)" in out  # the refused `go 10`
    assert "e-stop reset" in out and "wrist -> 10.0 deg" in out
    assert main(["estop", "--status"]) == 0 and "not latched" in capsys.readouterr().out


def test_a_show_stops_when_the_estop_is_pressed_in_another_process(hand):
    from hardware.player import Player, StopReason

    cal = default_calibration(hand)
    t = np.arange(0, 3.0, 1 / 40)
    q = np.tile(np.clip(hand.rest_pose(), cal.lower, cal.upper), (len(t), 1))
    q[:, 0] = 0.3 * np.sin(t)
    with ServoSession(calibration=cal) as s:
        player = Player(s.bus, cal)
        timer = threading.Timer(0.5, estop.set_latch, args=("shadow-studio estop",))
        timer.start()
        result = player.play(t, q, hand.joint_names)
        timer.join()
        assert result.reason == StopReason.ESTOP and 10 < len(result.sent) < 40, (result.reason, len(result.sent))
        again = player.play(t, q, hand.joint_names)  # refused at once, saying by whom
        assert again.reason == StopReason.ESTOP and len(again.sent) == 0
        assert "the e-stop is latched (set by shadow-studio estop" in again.message
