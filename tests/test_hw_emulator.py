"""The servo emulator's lifecycle: a context manager that closes every descriptor and thread it opens."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest

from hardware.emulator import ServoEmulator
from hardware.serial_bus import BusConfig, SerialServoBus

FDS = Path("/proc/self/fd")


def open_fds() -> set[str]:
    return set(os.listdir(FDS))


def emulator_threads() -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == "servo-emulator"]


@pytest.mark.skipif(not FDS.is_dir(), reason="needs /proc/self/fd (Linux) to count open descriptors")
def test_emulator_leaves_no_fds_or_threads_behind():
    before = open_fds()
    for _ in range(3):
        with ServoEmulator(range(1, 4)) as emu, SerialServoBus(BusConfig(emu.port, timeout_s=0.05)) as bus:
            assert bus.read_position(1) == 500 and len(emulator_threads()) == 1
            assert len(open_fds()) >= len(before) + 3  # pty master, slave, and the host's port
    assert open_fds() == before and not emulator_threads()

    with pytest.raises(RuntimeError, match="boom"):
        with ServoEmulator(range(1, 4)) as emu:
            raise RuntimeError("boom")
    emu.stop()  # a second stop is harmless
    assert open_fds() == before and not emulator_threads()

    with ServoEmulator(range(1, 4)) as emu:
        with pytest.raises(RuntimeError, match="already running"):
            emu.start()  # a second start would leak the first pty
    assert open_fds() == before and not emulator_threads()
