"""The jog tool's logic, driven without a terminal, on the emulator through real pyserial."""

from __future__ import annotations

import math
import threading
import time

import numpy as np
import pytest

from hardware.calibration import default_calibration
from hardware.emulator import ServoEmulator
from hardware.errors import EStopLatched
from hardware.jog import Jog, JogConfig
from hardware.serial_bus import BusConfig, SerialServoBus


@pytest.fixture
def jog(hand):
    cal = default_calibration(hand)
    # 50 ms per answer: with the other core busy the emulator thread once missed 10 ms × every retry (a flake)
    with ServoEmulator(cal.ids) as emu, SerialServoBus(BusConfig(emu.port, timeout_s=0.05)) as bus:
        yield emu, Jog(bus, cal, config=JogConfig(speed_rad_s=20.0, min_move_s=0.0), home_pose=hand.rest_pose())


def settle():
    time.sleep(0.3)  # servo top speed: 1562 units/s


def test_select_step_go(jog):
    emu, j = jog
    assert j.select("index_pip") == "index_pip" and j.select(2) == "thumb_mcp_flex"
    with pytest.raises(ValueError, match="unknown joint"):
        j.select("toe")
    j.execute("j index_pip")
    j.execute("step 10")
    j.execute("+")
    out = j.execute("+")
    assert "index_pip -> 20.0 deg" in out
    settle()
    assert j.read()["index_pip"] == pytest.approx(math.radians(20), abs=0.005)
    assert j.execute("go -30").startswith("index_pip -> -30.0 deg")
    settle()
    assert j.read()["index_pip"] == pytest.approx(math.radians(-30), abs=0.005)
    assert j.read()["wrist"] == pytest.approx(0, abs=0.005)  # only the selected joint moved


def test_limits_clip_and_say_so(jog):
    emu, j = jog
    j.select("index_mcp_abd")  # URDF [-60°, 0°]
    m = j.go(math.radians(45))
    assert m.clipped and m.sent == pytest.approx(0.0)
    assert "clipped" in j.execute("go -90")
    assert j.target[j.index] == pytest.approx(j.cal.lower[j.index])


def test_home_torque_read_estop(jog, hand):
    emu, j = jog
    j.select("wrist")
    j.go(1.0)
    settle()
    assert "home" in j.execute("home")
    settle()
    assert np.allclose(j.read_array(), np.clip(hand.rest_pose(), j.cal.lower, j.cal.upper), atol=0.005)
    assert j.execute("off") == "torque off" and not j.bus.read_torque(1)  # a read follows the write
    emu.set_position(1, 600)  # move the limp wrist by hand
    assert "wrist=" in j.execute("read") and j.read()["wrist"] == pytest.approx(100 / 238.732, abs=1e-3)
    j.execute("on")
    assert j.bus.read_torque(1) and j.target[0] == pytest.approx(100 / 238.732, abs=1e-3)  # holds where it is
    j.cfg.speed_rad_s = 0.5
    j.go(-1.0)
    time.sleep(0.05)
    assert "E-STOP" in j.execute("stop")
    here = j.bus.read_position(1)  # answered after the stop was handled
    time.sleep(0.1)
    assert j.bus.read_position(1) == here and 400 < here < 600  # halted part-way
    assert "commands" in j.execute("help")
    assert "0:wrist" in j.execute("joints")
    with pytest.raises(ValueError, match="unknown command"):
        j.execute("fly")


def test_estop_latches_through_home(hand):
    """Home is a multi-batch move: an e-stop from another thread after its first batch keeps servos 8-21 where
    they are, and every move is refused until reset."""
    cal = default_calibration(hand)
    home = np.clip(np.full(21, 0.3), cal.lower, cal.upper)
    with ServoEmulator(cal.ids) as emu, SerialServoBus(BusConfig(emu.port, timeout_s=0.01, batch_gap_s=0.5)) as bus:
        j = Jog(bus, cal, config=JogConfig(speed_rad_s=0.5), home_pose=home)

        def press():
            deadline = time.perf_counter() + 5
            while emu.servo(7).last_move == (500, 0) and time.perf_counter() < deadline:
                time.sleep(0.001)
            assert "E-STOP" in j.execute("stop")

        presser = threading.Thread(target=press)
        presser.start()
        with pytest.raises(EStopLatched) as info:
            j.home()
        presser.join()
        assert sorted(info.value.sent) == list(range(1, 8))
        j.bus.read_position(21)  # answered after everything before it was handled
        assert all(emu.servo(i).last_move == (500, 0) for i in range(8, 22))
        for line in ("home", "go 20", "+", "on"):
            with pytest.raises(EStopLatched):
                j.execute(line)
        assert "e-stop reset" in j.execute("reset")
        bus.batch_gap_s = 0.01
        j.cfg.speed_rad_s = 20.0
        j.home()
        j.bus.read_position(21)
        want = np.round(cal.to_units(home)).astype(int)
        assert [emu.servo(i).last_move[0] for i in cal.ids] == want.tolist()


def test_typed_angles_must_be_finite(jog):
    emu, j = jog
    j.select("wrist")
    refused = {
        "go nan": "go nan: give a finite number of degrees",
        "go inf": "go inf: give a finite",
        "go -inf": "go -inf: give a finite",
        "go ten": "go ten: give a finite",
        "step nan": "step nan: give a number of degrees above 0",
        "step 0": "step 0: give a number",
    }
    for line, words in refused.items():
        with pytest.raises(ValueError, match=words):
            j.execute(line)
    with pytest.raises(ValueError, match="give a finite angle"):
        j.go(math.nan)
    j.bus.read_position(1)
    assert emu.servo(1).last_move == (500, 0) and j.target[0] == pytest.approx(0.0)  # nothing was sent
    assert "wrist -> 10.0 deg" in j.execute("go 10")


def test_estop_from_jog_latches_for_every_process_and_reset_clears_it(jog, estop_file):
    emu, j = jog
    assert "E-STOP" in j.execute("stop")
    assert estop_file.is_file() and "jog on servo bus" in estop_file.read_text()
    with pytest.raises(EStopLatched, match="set by jog"):
        j.go(0.1)
    assert "e-stop reset" in j.execute("reset") and not estop_file.exists() and not j.bus.estop_latched
