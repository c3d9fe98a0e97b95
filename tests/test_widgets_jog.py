"""The Jog panel driven without a browser, against the emulator through real pyserial: sliders move servos (read
back from the emulator), stop at the soft limits, the e-stop latches until reset, a lost port disables the sliders
with a message."""

from __future__ import annotations

import math
import time
from dataclasses import replace

import ipywidgets as W
import numpy as np
import pytest
from studio.assets import asset

from hardware.calibration import load_calibration
from hardware.jog import JogConfig
from studio.project.jobs import queue_for
from studio.project.project import Project
from widgets.images import mask_picture
from widgets.jog import JogPanel, JogPanelConfig, jog_panel
from widgets.sculpt import PX
from widgets.state import StudioState

STILL = asset("targets/asl_o.jpeg")
FAST = JogPanelConfig(jog=JogConfig(speed_rad_s=20.0, min_move_s=0.0), refresh_hz=10.0, timeout_s=0.05)


@pytest.fixture
def state(tmp_path):
    project = Project.create(tmp_path / "jog.shadow", sources=[STILL])
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


@pytest.fixture
def panel(state, hand):
    p = JogPanel(state, config=FAST, hand=hand)
    yield p
    p.close()


def settle() -> None:
    time.sleep(0.4)  # the virtual servos' top speed is 1562 units/s


def emulator_rad(p: JogPanel) -> np.ndarray:
    """(J,) rad the emulator's encoders read now, calibration order."""
    units = p.emulator.positions()
    return p.cal.to_rad(np.array([units[i] for i in p.cal.ids], float))


def measured_deg(p: JogPanel, j: int) -> float:
    """The read-back label of joint ``j``, degrees."""
    return float(p.measured[j].value.removeprefix("measured ").removesuffix("°"))


def wait_until(test, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while not test() and time.monotonic() < deadline:
        time.sleep(0.02)
    return test()


@pytest.mark.slow
def test_a_slider_moves_its_servo_and_stops_at_the_soft_limit(panel, hand):
    assert "Jog" in panel.title.value and panel.jog is None and "shadow only" in panel.message.value
    panel.connect_button.click()
    assert panel.emulator is not None and not any(s.disabled for s in panel.sliders), panel.message.value
    j = panel.cal.joint_names.index("index_pip")
    lo, hi = panel.cal.lower[j], panel.cal.upper[j]
    assert panel.sliders[j].min == pytest.approx(math.degrees(lo)) and panel.sliders[j].max == pytest.approx(
        math.degrees(hi))  # fmt: skip
    # beside each slider its range, so one at an end reads as the end of its joint (abductions end near 0°)
    a = panel.cal.joint_names.index("index_mcp_abd")
    assert panel.spans[a].value == f"−{-math.degrees(panel.cal.lower[a]):.0f}…{math.degrees(panel.cal.upper[a]):.0f}°"
    assert panel.sliders[a].value == pytest.approx(panel.sliders[a].max)
    before = emulator_rad(panel)
    panel.sliders[j].value = 20.0
    settle()
    now = emulator_rad(panel)
    assert now[j] == pytest.approx(math.radians(20), abs=0.01)
    others = np.arange(len(now)) != j
    assert np.allclose(now[others], before[others], atol=0.01)  # only that servo moved
    panel.read_button.click()
    assert measured_deg(panel, j) == pytest.approx(20.0, abs=0.3)
    panel.sliders[j].value = 10_000.0  # past the end: the slider stops at the soft limit, and so does the servo
    assert panel.sliders[j].value == pytest.approx(math.degrees(hi))
    assert wait_until(lambda: abs(emulator_rad(panel)[j] - hi) < 0.01), emulator_rad(panel)[j]
    m = panel.move("index_pip", -10_000.0)  # asked in code: clipped, and said so
    assert m.clipped and m.sent == pytest.approx(lo) and "clipped" in panel.message.value
    assert panel.sliders[j].value == pytest.approx(math.degrees(lo))
    assert wait_until(lambda: abs(emulator_rad(panel)[j] - lo) < 0.01), emulator_rad(panel)[j]


def test_estop_latches_until_reset(panel):
    assert panel.connect()
    j = panel.cal.joint_names.index("wrist")
    servo = panel.emulator.servo(panel.cal.ids[j])
    panel.sliders[j].value = 15.0
    panel.estop_button.click()
    assert "E-STOP" in panel.message.value and all(s.disabled for s in panel.sliders)
    assert panel.bus.estop_latched and not panel.reset_button.disabled
    panel.bus.read_position(1)  # answered once everything before it was handled
    seen, last = panel.emulator.packets_seen, servo.last_move
    panel.sliders[j].value = -30.0  # a move while latched sends nothing
    panel.home_button.click()
    panel.bus.read_position(1)
    assert panel.emulator.packets_seen == seen + 1 and servo.last_move == last
    assert "latched" in panel.message.value
    panel.reset_button.click()
    assert not panel.bus.estop_latched and not any(s.disabled for s in panel.sliders), panel.message.value
    panel.sliders[j].value = -30.0
    settle()
    assert emulator_rad(panel)[j] == pytest.approx(math.radians(-30), abs=0.01)


def test_a_lost_port_leaves_the_sliders_shaping_the_shadow_only_with_a_message(panel):
    assert panel.connect()
    panel.emulator.stop()  # the adapter is pulled
    panel.sliders[0].value = 5.0
    assert panel.jog is None and panel.emulator is None and all(b.disabled for b in panel.moves)
    assert (
        "lost the servo bus" in panel.message.value
        and "shadow only" in panel.message.value
        and "Traceback" not in panel.message.value
    )
    assert not panel.connect_button.disabled
    panel.read_button.click()  # nothing to read: still a message, never an exception
    assert panel.connect() and not panel.sliders[0].disabled  # connecting again works
    panel.auto.value = True  # the periodic read-back finds the lost port from its thread
    assert wait_until(lambda: panel.measured[0].value.startswith("measured ") and "?" not in panel.measured[0].value)
    panel.emulator.stop()
    assert wait_until(lambda: panel.jog is None and all(b.disabled for b in panel.moves))
    assert "lost the servo bus" in panel.message.value and panel.auto.value is False


@pytest.mark.slow
def test_torque_home_and_the_selected_keyframes_pose(state, hand):
    cal = load_calibration(None, hand)
    k = state.project.keyframes[0].id
    pose = hand.rest_pose().copy()
    pose[cal.joint_names.index("index_pip")] = 0.6
    pose[cal.joint_names.index("middle_pip")] = 0.4
    pose[cal.joint_names.index("ring_pip")] = hand.upper[hand.joint_names.index("ring_pip")]  # 0.05 rad past the soft
    state.edit("set_result", k, pose, {"total": 0.5}, state.project.keyframe_masks(k)[0])
    p = jog_panel(state, config=FAST)
    assert state.extras["jog"] is p and isinstance(p.widget, W.VBox)
    p.go_keyframe()
    assert "not connected" in p.message.value
    assert p.connect()
    state.select(keyframe=k)
    assert p.keyframe_button.description == f"go to keyframe {k}"
    p.keyframe_button.click()
    assert f"keyframe {k}'s pose" in p.message.value, p.message.value
    assert "stopped at the soft limits (ring_pip by 2.9°)" in p.message.value, p.message.value
    settle()
    assert np.allclose(emulator_rad(p), np.clip(pose, cal.lower, cal.upper), atol=0.01)
    assert p.sliders[cal.joint_names.index("index_pip")].value == pytest.approx(math.degrees(0.6))
    p.home_button.click()
    settle()
    assert np.allclose(emulator_rad(p), np.clip(hand.rest_pose(), cal.lower, cal.upper), atol=0.01)
    p.torque_off_button.click()
    assert not p.bus.read_torque(cal.ids[0]) and "limp" in p.message.value
    p.emulator.set_position(cal.ids[0], cal.to_units(np.full(21, 0.3))[0])  # the limp wrist moved by hand
    p.read_button.click()
    assert measured_deg(p, 0) == pytest.approx(math.degrees(0.3), abs=0.3)
    p.torque_on_button.click()
    assert p.bus.read_torque(cal.ids[0]) and p.sliders[0].value == pytest.approx(math.degrees(0.3), abs=0.3)
    emulator = p.emulator
    p.disconnect_button.click()
    assert "servos stopped, torque held" in p.message.value and p.emulator is None and emulator._thread is None
    p.close()
    assert "jog" not in state.extras


def test_disconnect_stops_and_releases_torque_when_configured(state, hand):
    p = JogPanel(state, config=replace(FAST, release_on_close=True), hand=hand)
    try:
        assert p.connect()
        p.home_button.click()  # every servo loaded
        p.read_button.click()  # answered once every move before it was handled
        emulator = p.emulator
        assert all(s.torque for s in emulator.servos)
        p.disconnect_button.click()
        assert "servos stopped, torque released" in p.message.value and emulator._thread is None
        assert not any(s.torque for s in emulator.servos)  # the emulator's own servos, read after it stopped
    finally:
        p.close()


def test_the_panels_estop_is_every_processs_and_a_latch_set_elsewhere_holds_here(panel, estop_file):
    """The e-stop button writes the shared latch (a `play` in another process is refused); connecting while a latch
    set elsewhere holds says so and moves nothing until reset, which clears it for every process."""
    from hardware import estop

    assert panel.connect()
    panel.estop_button.click()
    assert estop_file.is_file() and "jog on servo bus" in estop.read_latch().by
    panel.disconnect()
    assert estop.is_latched()  # the latch outlives the connection (and the process)
    assert panel.connect()
    assert "the e-stop is latched (set by jog" in panel.message.value and "press reset" in panel.message.value
    assert panel.bus.estop_latched and all(s.disabled for s in panel.sliders)
    panel.reset_button.click()
    assert not estop.is_latched() and not any(s.disabled for s in panel.sliders), panel.message.value


def test_sculpting_without_servos_shows_the_shadow_and_saves_a_keyframe(panel, state, hand):
    """Disconnected, the sliders shape the shadow alone (pixels change with a joint); the pose is kept as the
    keyframe result of the frame in view, current, with the loss the caption showed."""
    assert panel.sculpt.drawer.settle()  # drawn in the view's own thread
    before = panel.sculpt.commanded_shadow.copy()
    assert not panel.sliders[0].disabled and panel.jog is None
    wrist = next(k for k, n in enumerate(panel.cal.joint_names) if "wrist" in n)
    s = panel.sliders[wrist]
    s.value = s.max
    assert panel.sculpt.drawer.settle()
    after = panel.sculpt.commanded_shadow
    assert after.sum() > 50 and (before != after).sum() > 20  # a black shadow that moved with the wrist
    assert panel.sculpt.measured_shadow is None and "loss" in panel.sculpt.caption.value
    theta = panel.commanded_pose()
    assert theta[hand.joint_names.index(panel.cal.joint_names[wrist])] == pytest.approx(np.radians(s.max))
    panel.sculpt.save_button.click()
    k = next(kf.id for kf in state.project.keyframes if kf.representative == state.selection.frame)
    r = state.project.results[k]
    assert not state.project.is_stale(k) and np.array_equal(r.shadow, after)
    assert np.allclose(r.theta(hand.joint_names), np.clip(theta, hand.lower, hand.upper))
    assert f"saved as keyframe {k}" in panel.sculpt.messages.text


def test_a_slider_never_waits_for_the_shadow_and_the_newest_pose_is_drawn(panel, monkeypatch):
    """The shadow is rendered and scored in the view's own thread: with a draw held, a slider's handler returns at
    once, and once the draw goes on the pictures show the slider's newest pose, not the one held."""
    import threading

    from studio.project.sculpt import Sculptor

    assert panel.sculpt.drawer.settle()
    release, held, real = threading.Event(), threading.Event(), Sculptor.score

    def slow_score(self, *args):
        held.set()
        release.wait(30)
        return real(self, *args)

    monkeypatch.setattr(Sculptor, "score", slow_score)
    s = panel.sliders[next(k for k, n in enumerate(panel.cal.joint_names) if "wrist" in n)]
    try:
        s.value = s.min
        assert held.wait(10)  # a draw is now held in the view's thread
        moved = threading.Thread(target=lambda: setattr(s, "value", s.max))
        moved.start()
        moved.join(5)
        assert not moved.is_alive(), "the slider's handler waited for the held draw"
    finally:
        release.set()
    assert panel.sculpt.drawer.settle()
    newest = panel.sculpt.sculptor.shadow(panel.state.project, panel.commanded_pose())
    assert np.array_equal(panel.sculpt.commanded_shadow, newest)
    assert panel.sculpt.commanded_image.value == mask_picture(newest, PX)


def test_connected_the_measured_shadow_follows_the_servos(panel, hand):
    assert panel.connect()
    assert wait_until(lambda: panel.sculpt.measured_shadow is not None)
    panel.home()
    settle()
    panel.read()
    time.sleep(0.15)  # past the read-back throttle
    panel.read()
    assert panel.sculpt.drawer.settle()
    assert panel.sculpt.measured_shadow is not None and panel.sculpt.measured_shadow.any()
    panel.disconnect()
    assert panel.sculpt.drawer.settle() and panel.sculpt.measured_shadow is None


def test_the_estop_button_looks_latched_until_reset(panel):
    """A person sees the latch on the button itself: solid dark red, a lock and "LATCHED — reset" while it holds."""
    from widgets.jog import ESTOP_LATCHED_COLOUR

    assert panel.connect()
    b = panel.estop_button
    plain = (b.description, b.icon, b.style.button_color, b.button_style)
    assert plain == ("E-STOP", "stop", None, "danger")
    b.click()
    assert b.description == "E-STOP LATCHED — reset" and b.icon == "lock"
    assert b.style.button_color == ESTOP_LATCHED_COLOUR and b.button_style == "danger"
    assert (b.description, b.icon, b.style.button_color) != plain[:3]
    panel.home_button.click()  # refused while latched: the look stays
    assert b.description == "E-STOP LATCHED — reset"
    panel.reset_button.click()
    assert (b.description, b.icon, b.style.button_color, b.button_style) == plain
