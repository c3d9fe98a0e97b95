"""The pyserial bus against the emulator on a real pseudo-terminal: answers, echo, batching, faults, scan."""

from __future__ import annotations

import threading
import time

import pytest
import serial

from hardware import constants as C
from hardware.bus import is_motion, scan
from hardware.emulator import EmulatorConfig, ServoEmulator
from hardware.errors import BusError, ChecksumError, EStopLatched, HardwareError, ServoTimeout, UnexpectedReply
from hardware.protocol import StreamDecoder, encode_request
from hardware.serial_bus import BusConfig, SerialServoBus
from studio.cli.runs import advice


@pytest.fixture(params=[False, True], ids=["plain", "echo"])
def rig(request):
    echo = request.param
    with ServoEmulator(range(1, 22), EmulatorConfig(echo=echo)) as emu:
        with SerialServoBus(BusConfig(emu.port, timeout_s=0.05, retries=1, echo=echo)) as bus:
            yield emu, bus


def test_emulator_answers_byte_exact_over_raw_pyserial():
    with ServoEmulator(range(1, 4), EmulatorConfig(echo=True)) as emu:
        port = serial.Serial(emu.port, 115200, timeout=0.2)
        port.write(encode_request(2, C.VIN_READ))
        echo_and_reply = port.read(6 + 8)
        assert echo_and_reply[:6] == encode_request(2, C.VIN_READ)  # the adapter's echo comes first
        assert echo_and_reply[6:].hex(" ") == "55 55 02 05 1b e8 1c d9"  # 7400 mV
        port.write(encode_request(9, C.POS_READ) + encode_request(254, C.MOVE_STOP))  # absent ID, broadcast write
        assert port.read(100) == encode_request(9, C.POS_READ) + encode_request(254, C.MOVE_STOP)  # echo only
        port.close()


@pytest.mark.slow
def test_reads_writes_and_registers(rig):
    emu, bus = rig
    assert bus.read_positions([1, 2, 3]) == {1: 500, 2: 500, 3: 500}
    assert bus.read_voltage(5) == pytest.approx(7.4) and bus.read_temperature(5) == 38 and bus.read_faults(5) == 0
    sent = bus.write_positions({1: 640.4, 2: 1200, 3: -7}, 0.05)
    assert sent == {1: 640, 2: 1000, 3: 0}  # rounded and clamped to the servo's range, and reported
    time.sleep(0.45)  # 500 units at the servo's top speed take 0.32 s
    assert bus.read_positions([1, 2, 3]) == {1: 640, 2: 1000, 3: 0}
    assert bus.request(1, C.MOVE_TIME_READ) == (640, 50)
    assert bus.read_torque(1) is True
    bus.set_torque(False)
    assert bus.read_torque(1) is False and bus.read_torque(21) is False
    bus.send([(4, C.ANGLE_LIMIT_WRITE, (100, 900)), (4, C.TEMP_MAX_LIMIT_WRITE, (75,))])
    assert bus.request(4, C.ANGLE_LIMIT_READ) == (100, 900) and bus.request(4, C.TEMP_MAX_LIMIT_READ) == (75,)
    bus.send([(6, C.ANGLE_OFFSET_ADJUST, (-20,)), (6, C.ANGLE_OFFSET_WRITE, ())])
    assert bus.request(6, C.ANGLE_OFFSET_READ) == (-20,) and emu.servo(6).saved_offset == -20
    bus.send([(7, C.VIN_LIMIT_WRITE, (6000, 8400)), (7, C.LED_ERROR_WRITE, (3,))])
    assert bus.request(7, C.VIN_LIMIT_READ) == (6000, 8400) and bus.request(7, C.LED_ERROR_READ) == (0,)
    assert bus.ping(8) and not bus.ping(30)


def test_wait_write_then_broadcast_start_and_stop(rig):
    emu, bus = rig
    bus.send([(i, C.MOVE_TIME_WAIT_WRITE, (800, 0)) for i in (1, 2)])
    assert bus.request(1, C.MOVE_TIME_WAIT_READ) == (800, 0)
    time.sleep(0.05)
    assert bus.read_position(1) == 500  # waiting for MOVE_START
    bus.send([(C.BROADCAST_ID, C.MOVE_START, ())])
    time.sleep(0.08)
    bus.stop()  # halts mid-move
    p1 = bus.read_position(1)
    time.sleep(0.1)
    assert 500 < p1 < 800 and bus.read_position(1) == p1 and abs(bus.read_position(2) - p1) <= 5


def test_id_write(rig):
    emu, bus = rig
    bus.send([(21, C.ID_WRITE, (40,))])
    assert bus.request(40, C.ID_READ) == (40,)
    assert not bus.ping(21)


def test_batches_keep_the_paper_gap():
    with ServoEmulator(range(1, 22)) as emu, SerialServoBus(BusConfig(emu.port)) as bus:
        t = time.perf_counter()
        bus.write_positions({i: 600 for i in range(1, 22)}, 0.1)
        assert time.perf_counter() - t >= 2 * 0.010  # 3 batches of 7, 10 ms between batches
        time.sleep(0.2)
        assert set(bus.read_positions(range(1, 22)).values()) == {600}


@pytest.mark.parametrize(
    "fault, error",
    [
        ({"drop_ids": {3}}, ServoTimeout),
        ({"missing_ids": {3}}, ServoTimeout),
        ({"corrupt_ids": {3}}, ChecksumError),
        ({"wrong_id_ids": {3}}, UnexpectedReply),
    ],
)
def test_injected_faults_raise_typed_errors(rig, fault, error):
    emu, bus = rig
    emu.inject(**fault)
    with pytest.raises(error) as info:
        bus.read_position(3)
    if error is ServoTimeout:
        assert info.value.servo_id == 3 and "cable, power and ID" in str(info.value) and "scan" in advice(info.value)
    assert bus.read_position(4) == 500  # the rest of the bus is fine
    emu.inject(drop_ids=set(), missing_ids=set(), corrupt_ids=set(), wrong_id_ids=set())
    assert bus.read_position(3) == 500


def test_retries_ride_out_occasional_drops_and_noise():
    with ServoEmulator(range(1, 22), EmulatorConfig(seed=3)) as emu:
        emu.inject(drop_rate=0.2, corrupt_rate=0.2)
        # 50 ms an answer: a drop costs one wait, and a loaded machine (two test workers) still answers in time
        with SerialServoBus(BusConfig(emu.port, timeout_s=0.05, retries=6)) as bus:
            for _ in range(3):
                assert set(bus.read_positions(range(1, 22)).values()) == {500}
            assert bus.stats["retries"] > 0 and bus.stats["checksum_errors"] > 0 and bus.stats["timeouts"] > 0


def test_thread_safe_requests(rig):
    emu, bus = rig
    errors = []

    def worker(ids):
        try:
            for _ in range(10):
                assert bus.read_positions(ids) == {i: 500 for i in ids}
        except Exception as e:  # noqa: BLE001 - collected and asserted below
            errors.append(e)

    threads = [threading.Thread(target=worker, args=(ids,)) for ids in ([1, 2, 3], [10, 11], [20, 21])]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors


def test_scan_finds_servos_and_flags_duplicates():
    with ServoEmulator([1, 2, 3, 5], duplicate_ids=(2,)) as emu:
        # no retries, so a present servo must answer within the wait even on a loaded machine: 0.1 s, not 10 ms
        with SerialServoBus(BusConfig(emu.port, timeout_s=0.1, retries=0)) as bus:
            bus.write_positions({1: 600, 2: 600, 3: 600, 5: 600}, 0.0)
            time.sleep(0.2)  # both servos with ID 2 now sit at 600: only their other readings differ
            report = scan(bus, range(0, 8), expected=[1, 2, 3, 4, 5])
    assert report.present == [1, 3, 5] and report.duplicates == [2] and report.missing == [4]


def test_echo_mismatch_and_bad_port():
    with ServoEmulator(range(1, 3)) as emu:  # no echo, but the bus expects one
        with SerialServoBus(BusConfig(emu.port, timeout_s=0.01, echo=True)) as bus:
            with pytest.raises(UnexpectedReply, match="echo"):
                bus.stop()
    with pytest.raises(BusError, match="cannot open"):
        SerialServoBus("/dev/does-not-exist").connect()
    with pytest.raises(BusError, match="not connected"):
        SerialServoBus("/dev/null").read_position(1)


def test_stuck_and_hot_servos_report_faults(rig):
    emu, bus = rig
    emu.inject(stuck_ids={2}, hot_ids={4})
    bus.move_batch({2: 800}, 0.05)
    time.sleep(0.1)
    assert bus.read_position(2) == 500 and bus.read_faults(2) & C.FAULT_LOCKED_ROTOR
    assert bus.read_temperature(4) == 92 and bus.read_faults(4) == C.FAULT_OVER_TEMPERATURE
    assert StreamDecoder().feed(b"") == []


def test_a_lost_port_is_a_bus_error_naming_it(rig):
    """The adapter vanishes (the emulator closes its pty): every call fails as a BusError naming the port, whether
    pyserial raised SerialException, OSError or termios.error underneath."""
    emu, bus = rig
    assert bus.read_position(1) == 500
    port = emu.port
    emu.stop()
    calls = {
        "read": lambda: bus.read_position(1),  # reset_input_buffer raises termios.error first
        "reads": lambda: bus.read_positions([1, 2]),
        "stop": lambda: bus.stop(),
        "move": lambda: bus.move_batch({1: 600}, 0.1),
        "write_positions": lambda: bus.write_positions({i: 600 for i in range(1, 22)}, 0.1),
        "torque": lambda: bus.set_torque(False),
    }
    for name, call in calls.items():
        with pytest.raises(BusError) as info:
            call()
        assert port in str(info.value) and "failed" in str(info.value), name
        assert isinstance(info.value, HardwareError) and info.value.__cause__ is not None, name
    assert bus.estop() is False and bus.estop_latched  # the latch holds even though the halt could not go out
    bus.disconnect()  # closing a vanished port is not an error
    assert not bus.is_connected


def test_estop_from_another_thread_stops_a_multi_batch_move():
    """An e-stop while write_positions pauses after its first batch: servos 8-21 never get their targets, 1-7 halt,
    and nothing moves again until reset_estop()."""
    cfg = dict(timeout_s=0.01, batch_gap_s=0.5)
    with ServoEmulator(range(1, 22)) as emu, SerialServoBus(BusConfig(emu.port, **cfg)) as bus:
        halted = []

        def press():  # a UI thread, as soon as the first batch has reached the servos
            deadline = time.perf_counter() + 5
            while emu.servo(7).last_move[0] != 900 and time.perf_counter() < deadline:
                time.sleep(0.001)
            halted.append(bus.estop())

        presser = threading.Thread(target=press)
        presser.start()
        t = time.perf_counter()
        with pytest.raises(EStopLatched, match="latched") as info:
            bus.write_positions({i: 900 for i in range(1, 22)}, 1.0)  # 1 s moves: batch 1 still moving when stopped
        presser.join()
        assert halted == [True] and time.perf_counter() - t < 0.45  # the pause woke at the e-stop
        assert info.value.sent == {i: 900 for i in range(1, 8)}
        bus.read_position(21)  # answered after everything written before it was handled
        assert all(emu.servo(i).last_move == (500, 0) for i in range(8, 22))  # never commanded
        a = emu.positions()
        time.sleep(0.1)
        assert emu.positions() == a and all(a[i] < 900 for i in range(1, 8))  # 1-7 halted part-way

        refused = {
            "move": lambda: bus.move_batch({1: 100}, 0.1),
            "write_positions": lambda: bus.write_positions({1: 100}, 0.1),
            "torque on": lambda: bus.set_torque(True),
            "wait + start": lambda: bus.send([(1, C.MOVE_TIME_WAIT_WRITE, (100, 0)), (254, C.MOVE_START, ())]),
        }
        for name, call in refused.items():
            with pytest.raises(EStopLatched, match="reset"):
                call()
            assert bus.estop_latched, name
        bus.read_position(1)
        assert emu.servo(1).last_move == (900, 1000) and emu.servo(1).waiting_move is None  # nothing went out
        bus.stop()  # MOVE_STOP and torque-off still go out
        bus.set_torque(False, [21])
        assert not bus.read_torque(21) and bus.read_position(1) == round(a[1])  # reads are fine
        assert bus.estop_latched

        bus.reset_estop()
        bus.batch_gap_s = 0.01
        assert not bus.estop_latched and bus.write_positions({i: 300 for i in range(1, 22)}, 0.0)[21] == 300
        assert bus.request(21, C.MOVE_TIME_READ) == (300, 0)  # answered after the move was handled


def test_what_the_latch_refuses():
    assert is_motion((1, C.MOVE_TIME_WRITE, (500, 0))) and is_motion((254, C.MOVE_START, ()))
    assert is_motion((1, C.LOAD_OR_UNLOAD_WRITE, (1,))) and is_motion((1, C.OR_MOTOR_MODE_WRITE, (1, 0, 500)))
    assert not is_motion((254, C.MOVE_STOP, ())) and not is_motion((254, C.LOAD_OR_UNLOAD_WRITE, (0,)))
    assert not is_motion((1, C.ID_WRITE, (3,))) and not is_motion((1, C.LED_CTRL_WRITE, (1,)))
