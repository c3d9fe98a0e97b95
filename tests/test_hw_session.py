"""hardware.session against the real emulator through real pyserial over a pseudo-terminal (no mocks): opening and
reading back, the fail-safe close (stopped, torque as configured, proved from the emulator's own servos), one
clear typed error for a missing or busy port, opening and closing twice."""

from __future__ import annotations

import os
import sys
import threading
import time
from pathlib import Path

import pytest

from hardware import constants as C
from hardware.calibration import default_calibration
from hardware.errors import BusError
from hardware.serial_bus import EMULATOR_TIMEOUT_S, PORT_TIMEOUT_S, BusConfig
from hardware.session import ServoSession

FDS = Path("/proc/self/fd")


@pytest.fixture
def cal(hand):
    return default_calibration(hand)


def start_slow_move(bus, ids) -> None:
    """Every servo loaded and on its way to 900 units over 5 s: still moving when the session closes."""
    bus.write_positions({i: 900 for i in ids}, 5.0)
    bus.read_position(ids[-1])  # answered once every move before it was handled
    time.sleep(0.05)


def moving(emu, ids) -> list[int]:
    """The servos whose encoders change within 0.15 s (the emulator's servos keep their motion after it stops)."""
    before = emu.positions()
    time.sleep(0.15)
    after = emu.positions()
    return [i for i in ids if abs(after[i] - before[i]) > 0.5]


def torque(emu, ids) -> dict[int, bool]:
    """``{id: torque on}`` as the emulator's servos hold it."""
    return {i: emu.servo(i).torque for i in ids}


def emulator_threads() -> int:
    return sum(t.name == "servo-emulator" for t in threading.enumerate())


def test_opens_the_emulator_and_reads_back_every_servo(cal):
    with ServoSession(calibration=cal) as s:
        assert s.is_open and s.bus.config.port == s.emulator.port and s.bus.is_connected
        assert sorted(x.servo_id for x in s.emulator.servos) == cal.ids == list(range(1, 22))
        assert s.read_back() == {i: C.CENTER_UNITS for i in cal.ids}
        s.emulator.set_position(3, 321)  # turned by hand (torque off): the read-back is the servo's, not a cache
        s.emulator.inject(missing_ids={7})
        got = s.read_back()
    assert got[3] == 321 and got[7] is None and sum(v is not None for v in got.values()) == 20


def test_the_emulator_is_given_longer_to_answer_than_a_port_unless_the_link_says(cal):
    # its servos answer from a thread of this process, beside the studio's jobs (EMULATOR_TIMEOUT_S's comment)
    with ServoSession(calibration=cal) as s:
        assert s.bus.timeout_s == EMULATOR_TIMEOUT_S and s.read_back()[1] == C.CENTER_UNITS
        with ServoSession(s.emulator.port, config=BusConfig(s.emulator.port, exclusive=False), ids=[1]) as port:
            assert port.bus.timeout_s == PORT_TIMEOUT_S < EMULATOR_TIMEOUT_S  # a port: a servo answers in ~2 ms
    with ServoSession(calibration=cal, config=BusConfig("", timeout_s=0.05)) as s:
        assert s.bus.timeout_s == 0.05  # what the link asks for is kept


@pytest.mark.parametrize("release", [False, True], ids=["hold", "release"])
def test_a_closed_session_is_stopped_with_torque_as_configured_and_refuses_use(cal, release):
    s = ServoSession(calibration=cal, release_on_close=release).open()
    bus, emu = s.bus, s.emulator
    start_slow_move(bus, cal.ids)
    assert len(moving(emu, cal.ids)) == 21
    report = s.close()
    assert report.stopped and report.torque == ("released" if release else "held"), report.message
    assert report.torque_on == {i: not release for i in cal.ids}  # what the servos answered after the stop
    assert moving(emu, cal.ids) == [] and max(emu.positions().values()) < 700  # halted on the way
    assert torque(emu, cal.ids) == {i: not release for i in cal.ids}
    assert emu._thread is None and not s.is_open and not bus.is_connected  # the emulator and the port are closed
    for use in (lambda: s.bus, s.read_back, s.open):
        with pytest.raises(BusError, match="session on the servo emulator was closed: open a new one"):
            use()
    with pytest.raises(BusError, match="is not connected: it was closed"):
        bus.read_position(1)  # the bus it gave out is closed too


@pytest.mark.parametrize(
    "release, latched", [(False, False), (True, False), (True, True)], ids=["hold", "release", "release-latched"]
)
def test_an_exception_in_the_block_still_ends_stopped_with_torque_as_configured(cal, release, latched):
    with pytest.raises(RuntimeError, match="boom"):
        with ServoSession(calibration=cal, release_on_close=release) as s:
            start_slow_move(s.bus, cal.ids)
            if latched:  # an e-stop that holds torque: the closing torque-off still goes out
                assert s.bus.estop(release_torque=False)
            raise RuntimeError("boom")
    emu = s.emulator
    assert s.report.stopped and moving(emu, cal.ids) == [] and max(emu.positions().values()) < 700
    assert torque(emu, cal.ids) == {i: not release for i in cal.ids}, s.report.message
    assert emu._thread is None and not s.is_open


def test_a_port_lost_in_the_block_surfaces_and_the_close_says_so(cal):
    with pytest.raises(BusError, match="failed") as raised:
        with ServoSession(calibration=cal) as s:
            bus = s.bus
            s.emulator.stop()  # the adapter is pulled
            bus.read_position(1)
    assert "\n" not in str(raised.value)
    assert not s.report.stopped and s.report.torque == "unknown" and "cut their power" in s.report.message
    assert not bus.is_connected


def test_a_missing_port_is_one_clear_typed_error():
    s = ServoSession("/dev/does-not-exist")
    with pytest.raises(BusError) as raised:
        s.open()
    message = str(raised.value)
    assert message.startswith("cannot open servo bus '/dev/does-not-exist': no such port") and "\n" not in message
    assert not s.is_open
    with pytest.raises(BusError, match="no serial port given"):
        ServoSession("  ")


def test_a_busy_port_is_one_clear_typed_error(cal):
    with ServoSession(calibration=cal) as first:
        with pytest.raises(BusError) as raised:
            ServoSession(first.emulator.port).open()
        message = str(raised.value)
        assert "busy" in message and first.emulator.port in message and "\n" not in message
        assert first.read_back()[1] == C.CENTER_UNITS  # the first session still has the servos


def test_without_pseudo_terminals_the_emulator_is_one_clear_typed_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "pty", None)  # importing pty now fails, as on Windows
    monkeypatch.delitem(sys.modules, "hardware.emulator", raising=False)
    s = ServoSession()
    with pytest.raises(BusError, match="POSIX") as raised:
        s.open()
    assert "\n" not in str(raised.value) and not s.is_open


@pytest.mark.skipif(not FDS.is_dir(), reason="needs /proc/self/fd (Linux) to count open descriptors")
def test_opening_twice_and_closing_twice_are_safe(cal):
    before = set(os.listdir(FDS))
    s = ServoSession(calibration=cal)
    assert s.open() is s and s.open() is s  # the second open changes nothing: one emulator, one port
    bus, emu = s.bus, s.emulator
    assert emulator_threads() == 1 and s.bus is bus and s.emulator is emu
    with s:  # entering an open session keeps it; leaving closes it
        assert s.read_back()[1] == C.CENTER_UNITS
    first = s.report
    assert first is not None and first.stopped and s.close() is first and s.close() is first
    other = ServoSession(calibration=cal).open()
    reports: list = []
    closers = [threading.Thread(target=lambda: reports.append(other.close())) for _ in range(4)]
    for t in closers:
        t.start()
    for t in closers:
        t.join()
    assert len(reports) == 4 and all(r is reports[0] for r in reports) and reports[0].stopped
    assert ServoSession().close().stopped is False  # never opened: nothing to stop, nothing raised
    assert set(os.listdir(FDS)) == before and emulator_threads() == 0


@pytest.mark.skipif(not FDS.is_dir(), reason="needs /proc/self/fd (Linux) to count open descriptors")
def test_a_failed_open_leaves_nothing_behind(cal):
    before = set(os.listdir(FDS))
    s = ServoSession(calibration=cal, config=BusConfig("", baud=-1))  # the emulator starts, the port cannot open
    with pytest.raises(ValueError, match="baudrate"):
        s.open()
    assert not s.is_open and set(os.listdir(FDS)) == before and emulator_threads() == 0
