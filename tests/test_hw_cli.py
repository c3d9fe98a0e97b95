"""The hardware verbs end to end: `emulate` in a subprocess, then scan / jog / calibrate / play against it."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from hardware.calibration import load_calibration
from studio.cli.main import main


@pytest.fixture
def emulate():
    """Start `shadow-studio emulate ARGS…` in a subprocess; returns the device path it prints."""
    procs = []

    def start(*args):
        proc = subprocess.Popen(
            [sys.executable, "-m", "studio.cli", "emulate", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        procs.append(proc)
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/"), proc.stderr.read()
        return port

    yield start
    for proc in procs:
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=10)
        assert proc.returncode == 0


def test_emulate_then_scan(emulate, capsys):
    assert main(["scan", "--port", emulate("--duplicate", "9"), "--ids", "0-24", "--timeout", "0.01"]) == 1
    out = capsys.readouterr().out
    assert "present: [1, 2, 3, 4, 5, 6, 7, 8, 10" in out and "DUPLICATE IDs" in out and "[9]" in out


def test_jog_and_calibrate_read_stdin(emulate, capsys, monkeypatch, tmp_path, hand):
    port = emulate("--echo")
    monkeypatch.setattr(sys, "stdin", io.StringIO("j wrist\ngo 10\nread\nbogus\nquit\n"))
    assert main(["jog", "--port", port, "--echo"]) == 0
    out = capsys.readouterr().out
    assert "wrist -> 10.0 deg" in out and "? unknown command" in out
    out_file = tmp_path / "cal.yaml"
    monkeypatch.setattr(sys, "stdin", io.StringIO("set\n" * 3 + "skip\n" * 20))
    assert main(["calibrate", "--port", port, "--echo", "--out", str(out_file)]) == 1  # input ran out
    assert "nothing saved" in capsys.readouterr().err and not out_file.exists()
    monkeypatch.setattr(sys, "stdin", io.StringIO("set\n" * 3 + "skip\n" * 21))
    assert main(["calibrate", "--port", port, "--echo", "--out", str(out_file)]) == 0
    assert "? wrist: limits [0.000, 0.000] rad around the zero are too narrow" in capsys.readouterr().out
    assert load_calibration(out_file, hand).ids == list(range(1, 22))


def test_play_dry_run(hand, tmp_path, capsys):
    from studio.motion.show import Show, save_show

    t = np.arange(0, 0.5, 1 / 40)
    q = np.tile(hand.rest_pose(), (len(t), 1))
    q[:, 0] = 0.3 * t
    save_show(Show.from_samples(hand, t, q, title="tiny"), tmp_path / "tiny.json")
    log = tmp_path / "log.npz"
    assert main(["play", str(tmp_path / "tiny.json"), "--dry-run", "--log", str(log)]) == 0
    out = capsys.readouterr().out
    assert "completed" in out and "torque held" in out and "jitter" in out
    saved = np.load(log)
    assert saved["sent"].shape == (len(t), 21) and len(saved["measured_rad"]) > 0
    assert main(["play", str(tmp_path / "tiny.json")]) == 2  # no port, no dry run: a one-line error
    assert "--port" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: nope\n")
    assert main(["play", str(tmp_path / "tiny.json"), "--dry-run", "--calibration", str(bad)]) == 2
    assert "not a calibration file" in capsys.readouterr().err
    assert load_calibration(None, hand).ids == list(range(1, 22))
