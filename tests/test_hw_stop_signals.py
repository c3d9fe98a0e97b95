"""A stop signal (SIGTERM, Ctrl-C, SIGHUP) ends `play` mid-show and `jog` while it waits: the stop packet reaches the
servos after the last move, torque held, the log written, one line naming the signal, exit code 128 + the signal
(DESIGN §5.13), against an emulator that records what it was sent."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from test_hw_cli import env
from test_play_verb import tiny_show

from hardware import constants as C
from hardware.calibration import default_calibration, save_calibration
from hardware.emulator import ServoEmulator


class RecordingEmulator(ServoEmulator):
    """The emulator, keeping ``(servo id, command code)`` of every packet the host sent (the stop packet is seen)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.seen: list[tuple[int, int]] = []

    def _handle(self, pkt):
        self.seen.append((pkt.servo_id, pkt.cmd))
        return super()._handle(pkt)

    def stopped_after_the_last_move(self) -> bool:
        """A MOVE_STOP broadcast arrived after the last move command."""
        moves = [k for k, (_, c) in enumerate(self.seen) if c == C.MOVE_TIME_WRITE.code]
        stops = [k for k, (i, c) in enumerate(self.seen) if c == C.MOVE_STOP.code and i == C.BROADCAST_ID]
        return bool(moves and stops and stops[-1] > moves[-1])


def _start(args: list[str], **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "studio.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env(), **kwargs)  # fmt: skip


@pytest.mark.parametrize(
    "signals, code, name",
    [
        ((signal.SIGTERM,), 143, "SIGTERM"),
        pytest.param((signal.SIGINT, signal.SIGINT), 130, "Ctrl-C", marks=pytest.mark.slow),  # twice: still 130
        pytest.param((signal.SIGHUP,), 129, "SIGHUP", marks=pytest.mark.slow),
    ],
)
def test_a_stop_signal_mid_show_stops_the_servos_writes_the_log_and_says_so(hand, tmp_path, signals, code, name):
    """`play` in a subprocess on a port, stopped mid-show by a signal: the stop packet reaches the servos after the
    last move, torque held, the log written, one line naming the signal, exit code 128 + the signal."""
    show = tiny_show(hand, tmp_path / "long.json", 6.0)
    cal = tmp_path / "cal.yaml"
    save_calibration(default_calibration(hand), cal)
    log = tmp_path / "run.npz"
    with RecordingEmulator(range(1, 22)) as emu:
        play = _start(["play", str(show), "--port", emu.port, "--calibration", str(cal), "--log", str(log), "--quiet"])
        try:
            assert play.stdout.readline().startswith("playing 'tiny'"), play.stderr.read()
            time.sleep(1.0)
            for sig in signals:
                play.send_signal(sig)
                time.sleep(0.02)
            out, err = play.communicate(timeout=60)
        finally:
            if play.poll() is None:
                play.kill()
        assert emu.stopped_after_the_last_move() and all(emu.servo(i).torque for i in range(1, 22))
        before = emu.positions()
        time.sleep(0.1)
        assert emu.positions() == before  # nothing moves after the verb ended
    said = [line for line in err.splitlines() if line.strip() and not line.startswith("INFO ")]
    lines = [line for line in said if "already stopping" not in line]  # what a second Ctrl-C prints meanwhile
    assert play.returncode == code, err
    assert len(lines) == 1 and f"play: stopped: interrupted: stopped by {name}; torque held" in lines[0], err
    saved = np.load(log)
    assert str(saved["reason"]) == "INTERRUPTED" and name in str(saved["message"]) and str(saved["torque"]) == "held"
    assert 10 < len(saved["sent"]) < 6 * 40 and f"saved to {log}" in out


def test_sigterm_ends_jog_with_the_servos_stopped_and_its_log(tmp_path):
    """`jog` waiting for its user, SIGTERM: the servos get the stop, one line, exit code 143, its log written."""
    log = tmp_path / "jog.txt"
    with RecordingEmulator(range(1, 22)) as emu:
        jog = _start(["jog", "--port", emu.port, "--log", str(log)], stdin=subprocess.PIPE)
        try:
            jog.stdin.write("go 20\n")
            jog.stdin.flush()
            for line in jog.stdout:
                if "wrist -> 20.0 deg" in line:
                    break
            jog.send_signal(signal.SIGTERM)
            out, err = jog.communicate(timeout=60)
        finally:
            if jog.poll() is None:
                jog.kill()
        assert emu.stopped_after_the_last_move() and emu.servo(1).torque
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("INFO ")]
    assert jog.returncode == 143 and len(lines) == 1, err
    assert "jog: stopped by SIGTERM: servos stopped, torque held" in lines[0]
    text = log.read_text()
    assert "> go 20" in text and "wrist -> 20.0 deg" in text and "end: stopped by SIGTERM" in text
    assert f"jog log saved to {log}" in out
