"""The show player against the emulator over real pyserial: reaching poses, clipping, clock, and safe stops."""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from hardware import constants as C
from hardware.calibration import Calibration, default_calibration
from hardware.emulator import EmulatorConfig, ServoEmulator
from hardware.player import Player, PlayerConfig, StopReason
from hardware.safety import SafetyConfig, clip_command
from hardware.serial_bus import BusConfig, SerialServoBus


@pytest.fixture
def cal(hand):
    base = default_calibration(hand)  # mixed directions and zeros exercise the conversion end to end
    return Calibration(tuple(replace(j, direction=-1 if k % 3 == 1 else 1, zero=500 + 5 * (k % 4)) for k, j in
                             enumerate(base.joints)))  # fmt: skip


@pytest.fixture
def rig(cal):
    with ServoEmulator(cal.ids) as emu, SerialServoBus(BusConfig(emu.port, timeout_s=0.05, retries=1)) as bus:
        yield emu, bus


def show(hand, seconds=1.0, amp=0.4):
    """A wave of every joint around the middle of its soft range: ``(times, positions, names)``."""
    t = np.arange(0, seconds + 1e-9, 1 / 40)
    mid = (hand.lower + hand.upper) / 2
    q = mid + amp * np.sin(2 * np.pi * t[:, None] / seconds + np.arange(21)) * 0.5
    return t, np.clip(q, hand.lower + 0.06, hand.upper - 0.06), hand.joint_names


def measured_rad(emu, cal, settle=0.06):
    time.sleep(settle)  # the last command still has one tick of move time to run
    pos = emu.positions()
    return cal.to_rad(np.array([pos[i] for i in cal.ids]))


@pytest.mark.slow
def test_reaches_the_shows_poses(hand, cal, rig):
    emu, bus = rig
    t, q, names = show(hand)
    seen = []
    player = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=2.0), on_sample=lambda tt, c, m: seen.append((tt, c, m)))
    r = player.play(t, q, names)
    assert r.ok and r.torque == "held", r.message
    assert r.ramp_ticks > 0 and len(r.sent) + r.skipped_ticks == r.ramp_ticks + len(t)
    k = np.round(r.t * 40).astype(int) - r.ramp_ticks  # show sample of each played tick (ticks may be skipped
    assert np.allclose(r.sent[k >= 0], q[k[k >= 0]], atol=1e-9)  # when the OS stalls us); nothing clipped
    assert not r.clipped_limit[r.ramp_ticks :].any() and not r.clipped_step.any()
    assert np.abs(measured_rad(emu, cal) - q[-1]).max() < 0.01  # ~1 servo unit of rounding
    assert r.commands == 21 * len(r.sent) and len(seen) == len(r.sent)
    assert len(r.measured_t) >= 3 * len(r.sent) - 3  # 3 position reads per tick
    assert r.max_tracking_error_rad < 0.1
    assert np.median(np.abs(r.lateness_s)) < 0.003


def test_show_columns_in_any_order(hand, cal, rig):
    emu, bus = rig
    t, q, names = show(hand, 0.3)
    perm = np.random.default_rng(0).permutation(21)
    r = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=50)).play(t, q[:, perm], [names[k] for k in perm])
    assert r.ok and np.allclose(r.sent[-1], q[-1])


def test_clipping_to_soft_limits_and_steps_is_reported(hand, cal, rig):
    emu, bus = rig
    t = np.arange(0, 0.75, 1 / 40)
    q = np.tile(np.clip(np.zeros(21), cal.lower, cal.upper), (len(t), 1))
    q[:, 0] = np.where(t < 0.25, 0.0, 3.0)  # beyond the wrist's soft limit, and a jump
    r = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=100)).play(t, q, hand.joint_names)
    assert r.ok
    k = r.ramp_ticks + 10
    assert r.clipped_limit[k:, 0].all() and r.clipped_step[k, 0] and not r.clipped_limit[:, 1:].any()
    step = np.diff(r.sent[:, 0])
    assert np.all(np.abs(step) <= 5.2 / 40 + 1e-9)  # never more than one step per tick
    assert r.sent[:, 0].max() == pytest.approx(cal.upper[0])  # ends at the soft limit, not at 3 rad
    assert np.all(r.requested[k:, 0] == 3.0)


def test_clip_command_laws():
    lo, hi = np.array([-1.0, 0.0]), np.array([1.0, 2.0])
    c = clip_command(np.array([5.0, 0.5]), np.array([0.0, 0.4]), lo, hi, 0.3)
    assert np.allclose(c.sent, [0.3, 0.5]) and c.at_limit.tolist() == [True, False] and c.at_step.tolist() == [1, 0]


@pytest.mark.slow
def test_steady_clock(hand, cal, rig):
    emu, bus = rig
    t, q, names = show(hand, 1.0)
    r = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=50)).play(t, q, names)
    late = np.abs(r.lateness_s)
    assert r.ok and np.percentile(late, 50) < 0.002  # absolute deadlines: no drift
    assert np.allclose(np.diff(r.t), 1 / 40) or r.skipped_ticks > 0  # a stall of > 1 tick skips, never slips


def test_over_temperature_stops_and_releases(hand, cal, rig):
    emu, bus = rig
    emu.inject(hot_ids={cal.ids[0]})
    t, q, names = show(hand, 1.0)
    r = Player(bus, cal, PlayerConfig(hold_torque_on_stop=False)).play(t, q, names)
    assert r.reason == StopReason.OVER_TEMPERATURE and "over-temperature" in r.message
    assert r.torque == "released" and not any(bus.read_torque(i) for i in cal.ids)


def test_stuck_servo_is_a_fault(hand, cal, rig):
    emu, bus = rig
    emu.inject(stuck_ids={cal.ids[0]})
    t, q, names = show(hand, 2.0, amp=1.0)
    r = Player(bus, cal).play(t, q, names)
    assert r.reason in (StopReason.FAULT, StopReason.TRACKING_ERROR), r.message
    assert r.torque == "held" and all(emu.servo(i).torque for i in cal.ids)


def test_stuck_servo_without_health_reads_is_a_tracking_error(hand, cal, rig):
    emu, bus = rig
    emu.inject(stuck_ids={cal.ids[0]})
    t, q, names = show(hand, 2.0, amp=1.0)
    r = Player(bus, cal, PlayerConfig(health_reads=False, ramp_speed_rad_s=50)).play(t, q, names)
    assert r.reason == StopReason.TRACKING_ERROR and "wrist" in r.message
    assert r.max_tracking_error_rad > 0.35


def test_lost_servo_mid_show(hand, cal, rig):
    emu, bus = rig
    t, q, names = show(hand, 3.0)

    def unplug(tt, c, m):
        if tt > 0.2:
            emu.inject(missing_ids={cal.ids[4]})

    r = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=50), on_sample=unplug).play(t, q, names)
    assert r.reason == StopReason.LOST_COMMUNICATION and "servo 5" in r.message
    assert len(r.sent) < len(t)


def test_no_servo_at_start(hand, cal, rig):
    emu, bus = rig
    emu.inject(missing_ids={3})
    t, q, names = show(hand, 0.3)
    r = Player(bus, cal).play(t, q, names)
    assert r.reason == StopReason.LOST_COMMUNICATION and "starting pose" in r.message and len(r.sent) == 0


@pytest.mark.slow
@pytest.mark.parametrize("how", ["estop", "cancel", "ctrl-c"])
def test_operator_stops(hand, cal, rig, how):
    emu, bus = rig
    t, q, names = show(hand, 3.0)
    cancel = threading.Event()
    player = None

    def hook(tt, c, m):
        if tt >= 0.25:
            if how == "estop":
                player.estop()
            elif how == "cancel":
                cancel.set()
            else:
                raise KeyboardInterrupt

    player = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=50), on_sample=hook)
    r = player.play(t, q, names, cancel=cancel)
    want = {"estop": StopReason.ESTOP, "cancel": StopReason.CANCELLED, "ctrl-c": StopReason.INTERRUPTED}[how]
    assert r.reason == want and r.torque == "held" and len(r.sent) < 20
    a = bus.read_positions(cal.ids)  # answered after the stop was handled
    time.sleep(0.1)
    assert bus.read_positions(cal.ids) == a  # halted: nothing moves after the stop


@pytest.mark.slow
def test_echo_adapter_and_bad_inputs(hand, cal):
    with ServoEmulator(cal.ids, EmulatorConfig(echo=True)) as emu:
        with SerialServoBus(BusConfig(emu.port, echo=True, timeout_s=0.05)) as bus:
            t, q, names = show(hand, 0.5)
            r = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=2.0)).play(t, q, names)
            assert r.ok and np.abs(measured_rad(emu, cal) - q[-1]).max() < 0.01
            with pytest.raises(ValueError, match="do not match"):
                Player(bus, cal).play(t, q[:, :20], names[:20])
            with pytest.raises(ValueError, match="strictly increasing"):
                Player(bus, cal).play(t[::-1], q, names)
    with pytest.raises(ValueError, match="do not fit"):
        Player(bus, cal, PlayerConfig(batch_spacing_s=0.015))


def test_safety_config_defaults_are_sane():
    s = SafetyConfig()
    assert s.max_temp_c < 85 and s.min_voltage_v < 7.4 < s.max_voltage_v and s.max_missed_reads >= 2


def test_emulator_stopped_mid_show_is_lost_communication(hand, cal, rig):
    """The adapter vanishes mid-show: a result (not an exception) saying so, with the ticks played so far."""
    emu, bus = rig
    t, q, names = show(hand, 3.0)
    port = emu.port

    def pull(tt, c, m):
        if tt >= 0.25 and emu.port:
            emu.stop()
            emu.port = ""

    player = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=50), on_sample=pull)
    r = player.play(t, q, names)
    assert r.reason == StopReason.LOST_COMMUNICATION and port in r.message, r.message
    assert r.torque == "unknown" and "cut the servos' power" in r.message  # the stop could not go out either
    assert 5 <= len(r.sent) < 20 and len(r.t) == len(r.sent) and player.last_result is r


def test_estop_from_a_second_thread_mid_show(hand, cal, rig):
    """No move goes out after the e-stop; the latch outlives play() and the next play() refuses at once."""
    emu, bus = rig
    t, q, names = show(hand, 3.0)
    player = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=50))
    after_estop = {}

    def press():
        time.sleep(0.4)
        assert player.estop()
        after_estop.update({i: emu.servo(i).last_move for i in cal.ids})

    presser = threading.Thread(target=press)
    presser.start()
    r = player.play(t, q, names)
    presser.join()
    assert r.reason == StopReason.ESTOP and 5 <= len(r.sent) < 40, r.message
    a = bus.read_positions(cal.ids)  # answered after everything the player sent was handled
    assert {i: emu.servo(i).last_move for i in cal.ids} == after_estop  # nothing was commanded after the e-stop
    time.sleep(0.1)
    assert bus.read_positions(cal.ids) == a and bus.estop_latched


@pytest.mark.parametrize("hold", [True, False], ids=["hold", "release"])
def test_a_latched_estop_is_not_cleared_by_play(hand, cal, rig, hold):
    emu, bus = rig
    t, q, names = show(hand, 0.3)
    bus.set_torque(True)  # loaded, so that releasing them shows
    assert bus.estop()
    bus.read_position(1)  # answered after the e-stop's MOVE_STOP was handled
    seen = emu.packets_seen
    player = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=50, hold_torque_on_stop=hold))
    r = player.play(t, q, names)
    assert r.reason == StopReason.ESTOP and "latched" in r.message and r.commands == 0 and len(r.sent) == 0
    assert r.torque == ("held" if hold else "released") and bus.estop_latched
    assert bus.read_torque(1) is hold  # the torque policy was applied
    assert emu.packets_seen - seen == (2 if hold else 3)  # MOVE_STOP (+ torque off), then our read: nothing else
    assert all(emu.servo(i).last_move == (500, 0) for i in cal.ids)
    bus.reset_estop()
    assert player.play(t, q, names).ok and not bus.estop_latched


@pytest.mark.parametrize("hook", ["on_sample", "progress"])
def test_a_raising_callback_stops_safely(hand, cal, rig, hook):
    emu, bus = rig
    t, q, names = show(hand, 3.0)

    def boom(*args):
        if (args[0] >= 0.25) if hook == "on_sample" else (args[0].step >= 10):  # t s, or a Progress
            raise RuntimeError("boom")

    player = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=50, hold_torque_on_stop=False))
    if hook == "on_sample":
        player.on_sample = boom
        r = player.play(t, q, names)
    else:
        r = player.play(t, q, names, progress=boom)
    assert r.reason == StopReason.CALLBACK_ERROR and f"{hook} callback raised RuntimeError: boom" in r.message
    assert r.torque == "released" and not any(bus.read_torque(i) for i in cal.ids)  # torque policy applied
    assert 5 <= len(r.sent) < 20 and player.last_result is r
    a = bus.read_positions(cal.ids)
    time.sleep(0.1)
    assert bus.read_positions(cal.ids) == a  # halted


def test_a_bug_stops_safely_then_surfaces(hand, cal, rig):
    """An unexpected exception inside the loop (here a broken config) still sends the stop and applies the torque
    policy, and leaves what was played in last_result, before it propagates."""
    emu, bus = rig
    t, q, names = show(hand, 1.0)
    player = Player(bus, cal, PlayerConfig(ramp_speed_rad_s=50, hold_torque_on_stop=False, reads_per_batch=None))
    with pytest.raises(TypeError):
        player.play(t, q, names)
    r = player.last_result
    assert r.reason == StopReason.ERROR and "TypeError" in r.message and r.torque == "released"
    assert len(r.sent) == 1 and r.commands == 7  # the first batch went out, then the bug
    assert bus.request(1, C.MOVE_TIME_READ)[1] == 25 and not bus.read_torque(1)
