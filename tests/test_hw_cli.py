"""The hardware verbs end to end: `emulate` in a subprocess, then scan / jog / calibrate / play against it (what
`play` checks and says before anything moves, and its dry run: test_play_verb.py)."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from test_play_verb import tiny_show

from hardware import constants as C
from hardware.calibration import default_calibration, load_calibration, save_calibration
from hardware.emulator import ServoEmulator
from studio.cli.main import main


def env() -> dict[str, str]:
    """The environment of a subprocess: this test's (its own e-stop latch file, conftest), unbuffered output."""
    return {**os.environ, "PYTHONUNBUFFERED": "1"}


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
            env=env(),
        )
        procs.append(proc)
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/"), proc.stderr.read()
        return port

    start.procs = procs
    yield start
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(timeout=10)
            assert proc.returncode == 0


def test_emulate_then_scan(emulate, capsys):
    # 0.2 s a read: an emulated servo answers within it even while the other test worker loads the cores
    assert main(["scan", "--port", emulate("--duplicate", "9"), "--ids", "0-24", "--timeout", "0.2"]) == 1
    out = capsys.readouterr().out
    assert "present: [1, 2, 3, 4, 5, 6, 7, 8, 10" in out and "DUPLICATE IDs" in out and "[9]" in out


def wait_until_still(port: str, servo_id: int, timeout_s: float = 5.0) -> None:
    """Read one servo over the bus until two reads 0.1 s apart agree (a jogged servo takes a while to arrive)."""
    from hardware.serial_bus import BusConfig, SerialServoBus

    with SerialServoBus(BusConfig(port, echo=True)) as bus:
        last, end = None, time.monotonic() + timeout_s
        while time.monotonic() < end:
            now = bus.read_position(servo_id)
            if now == last:
                return
            last = now
            time.sleep(0.1)
    raise AssertionError(f"servo {servo_id} still moving after {timeout_s} s")


def test_jog_and_calibrate_read_stdin(emulate, capsys, monkeypatch, tmp_path, hand):
    port = emulate("--echo")
    monkeypatch.setattr(sys, "stdin", io.StringIO("j wrist\ngo 10\nread\nbogus\nquit\n"))
    assert main(["jog", "--port", port, "--echo"]) == 0
    out = capsys.readouterr().out
    assert "wrist -> 10.0 deg" in out and "? unknown command" in out
    wait_until_still(port, servo_id=1)  # the jogged wrist must stop before its three "set"s read one position
    out_file = tmp_path / "cal.yaml"
    monkeypatch.setattr(sys, "stdin", io.StringIO("set\n" * 3 + "skip\n" * 20))
    assert main(["calibrate", "--port", port, "--echo", "--out", str(out_file)]) == 1  # input ran out
    assert "nothing saved" in capsys.readouterr().err and not out_file.exists()
    monkeypatch.setattr(sys, "stdin", io.StringIO("set\n" * 3 + "skip\n" * 21))
    assert main(["calibrate", "--port", port, "--echo", "--out", str(out_file)]) == 0
    assert "? wrist: limits [0.000, 0.000] rad around the zero are too narrow" in capsys.readouterr().out
    assert load_calibration(out_file, hand).ids == list(range(1, 22))


@pytest.mark.slow
def test_play_survives_the_emulator_dying(emulate, hand, tmp_path):
    """`emulate` is killed mid-show: play ends with one clear line on stderr, no traceback, and its log."""
    port = emulate()
    show = tiny_show(hand, tmp_path / "long.json", 6.0)
    cal = tmp_path / "cal.yaml"
    save_calibration(default_calibration(hand), cal)  # made for this hand: no warning about another one
    log = tmp_path / "run.npz"
    # --quiet: no progress bar on stderr, so the error is its only line
    args = ["play", str(show), "--port", port, "--calibration", str(cal), "--log", str(log), "--quiet"]
    play = subprocess.Popen(
        [sys.executable, "-m", "studio.cli", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env(),
    )
    try:
        assert play.stdout.readline().startswith("playing 'tiny'"), play.stderr.read()
        time.sleep(1.0)
        emulate.procs[0].kill()  # the adapter vanishes
        out, err = play.communicate(timeout=60)
    finally:
        if play.poll() is None:
            play.kill()
    lines = [line for line in err.splitlines() if line.strip()]
    assert play.returncode in (1, 2) and len(lines) == 1 and "Traceback" not in err, err
    assert "lost communication" in lines[0] and port in lines[0], lines[0]
    saved = np.load(log)
    assert str(saved["reason"]) == "LOST_COMMUNICATION" and port in str(saved["message"])
    assert 10 < len(saved["sent"]) < 6 * 40 and saved["sent"].shape[1] == 21 and len(saved["measured_rad"]) > 0
    assert f"saved to {log}" in out


def test_calibrate_checks_out_before_the_bus(tmp_path, capsys):
    no_port = ["calibrate", "--port", "/dev/does-not-exist", "--out"]
    assert main([*no_port, str(tmp_path / "missing" / "cal.yaml")]) == 2
    err = capsys.readouterr().err
    assert "does not exist" in err and "missing" in err and "servo bus" not in err and len(err.splitlines()) == 1
    assert main([*no_port, str(tmp_path)]) == 2
    assert "is a folder" in capsys.readouterr().err
    assert main([*no_port, str(tmp_path / "cal.yaml")]) == 2  # a good path: now the bus is the problem
    assert "cannot open servo bus" in capsys.readouterr().err


def test_calibrate_survives_missed_reads_and_keeps_progress_when_the_port_is_lost(tmp_path, capsys, monkeypatch, hand):
    out = tmp_path / "cal.yaml"
    with ServoEmulator(range(1, 22)) as emu:
        port = emu.port

        def session():  # what an operator types, while the hardware misbehaves between the lines
            yield "free\n"
            emu.set_position(1, 500)
            yield "set\n"  # wrist zero
            emu.inject(drop_ids={1})
            yield "set\n"  # a missed read: reported, nothing recorded
            emu.inject(drop_ids=set())
            emu.set_position(1, 400)
            yield "set\n"  # lower
            emu.set_position(1, 640)
            yield "set\n"  # upper: the wrist is calibrated
            emu.stop()  # the adapter is pulled
            yield "set\n"

        monkeypatch.setattr(sys, "stdin", session())
        assert main(["calibrate", "--port", port, "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert "? servo 1 did not answer" in captured.out and "thumb_mcp_abd" in captured.out
    assert "(shadow-studio scan --port PORT lists the servos that answer)" in captured.out  # the verb's advice
    err = captured.err.splitlines()
    partial = tmp_path / "cal.partial.yaml"
    assert len(err) == 1 and port in err[0] and str(partial) in err[0] and "--start" in err[0], err
    assert not out.exists()
    cal = load_calibration(partial, hand)  # a valid calibration to resume from
    w = cal.joint("wrist")
    assert (w.zero, w.direction) == (500, 1) and w.lower == pytest.approx(-100 / C.UNITS_PER_RAD, abs=1e-6)
    assert (
        w.upper == pytest.approx(140 / C.UNITS_PER_RAD, abs=1e-6)
        and cal.joints[1:] == load_calibration(None, hand).joints[1:]
    )


def test_jog_survives_missed_reads_and_ends_cleanly_on_a_lost_port(capsys, monkeypatch):
    with ServoEmulator(range(1, 22)) as emu:
        port = emu.port
        emu.inject(missing_ids={5})

        def session():
            yield "j 4\n"  # servo 5: its angle is unknown
            yield "+\n"  # it still does not answer: reported, the session goes on
            emu.inject(missing_ids=set())
            yield "+\n"  # now it does
            yield "stop\n"
            yield "go 10\n"  # refused: the e-stop is latched
            yield "reset\n"
            yield "go 10\n"
            emu.stop()
            yield "read\n"  # the port is gone

        monkeypatch.setattr(sys, "stdin", session())
        # 0.2 s a read: only the missing servo misses it, even while the other test worker loads the cores
        assert main(["jog", "--port", port, "--timeout", "0.2", "--retries", "0"]) == 2
    captured = capsys.readouterr()
    out = captured.out
    assert "? servos [5] did not answer" in out and "? servo 5 did not answer" in out
    assert "thumb_dip -> " in out and "E-STOP" in out and "? the e-stop is latched" in out
    assert "e-stop reset" in out and "thumb_dip -> 10.0 deg" in out
    err = captured.err.splitlines()
    assert len(err) == 1 and port in err[0] and "failed" in err[0], err


@pytest.mark.slow
def test_non_serial_verbs_need_no_pty_or_termios(hand, tmp_path):
    """On a system without pty/termios (Windows) the CLI builds, non-serial verbs run, and `emulate` says why it
    cannot run in one line."""
    show = tiny_show(hand, tmp_path / "s.json", 0.5)
    code = f"""
import sys
sys.modules["pty"] = sys.modules["termios"] = sys.modules["tty"] = None  # importing them now fails
from studio.cli.main import build_parser, main
build_parser()
assert main(["show-info", {str(show)!r}]) == 0
assert "hardware.emulator" not in sys.modules and "serial" not in sys.modules
assert main(["emulate"]) == 2
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env(), timeout=300)
    assert r.returncode == 0, r.stderr
    assert "tiny" in r.stdout and "POSIX" in r.stderr and "Traceback" not in r.stderr


def test_servo_ids_are_0_to_253_and_bad_lists_are_one_usage_line(in_process, hand, tmp_path):
    for args, words in [
        (("--ids", "0-300"), "argument --ids: '0-300' goes past 253: servo IDs are 0..253 (254 is the broadcast"),
        (("--ids", "254"), "servo ID 254 is outside 0..253"),
        (("--missing", "abc"), "argument --missing: 'abc' is not an ID or a range of IDs"),
        (("--duplicate", "9-3"), "argument --duplicate: '9-3' runs backwards"),
    ]:
        done = in_process("emulate", *args)
        assert done.returncode == 2 and done.stderr.count("\n") == 1 and words in done.stderr, done.stderr
        assert "invalid literal" not in done.stderr and "Traceback" not in done.stderr
    done = in_process("scan", "--port", "/dev/null", "--ids", "250-255")
    assert done.returncode == 2 and "'250-255' goes past 253" in done.stderr
    with pytest.raises(ValueError, match="servo ID 254 is outside 0..253"):
        ServoEmulator([1, 254])
    bad = tmp_path / "cal.yaml"
    save_calibration(default_calibration(hand), bad)
    bad.write_text(bad.read_text().replace("id: 21", "id: 254"))
    done = in_process("play", str(tiny_show(hand, tmp_path / "s.json", 0.2)), "--dry-run", "--calibration", bad)
    assert done.returncode == 2 and "servo ID 254 is outside 0..253" in done.stderr


def test_play_and_jog_keep_a_log_in_the_studio_home_by_default(hand, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("SHADOW_STUDIO_HOME", str(tmp_path / "home"))
    assert main(["play", str(tiny_show(hand, tmp_path / "s.json", 0.3)), "--dry-run", "--quiet"]) == 0
    [log] = (tmp_path / "home" / "logs").glob("play-*.npz")
    assert f"command vs measured saved to {log}" in capsys.readouterr().out
    assert str(np.load(log)["reason"]) == "COMPLETED"
    with ServoEmulator(range(1, 22)) as emu:
        monkeypatch.setattr(sys, "stdin", io.StringIO("j wrist\nquit\n"))
        assert main(["jog", "--port", emu.port]) == 0
    [journal] = (tmp_path / "home" / "logs").glob("jog-*.txt")
    assert f"jog log saved to {journal}" in capsys.readouterr().out
    text = journal.read_text()
    assert f"# shadow-studio jog on {emu.port}" in text and "> j wrist" in text and "end: servos stopped" in text
