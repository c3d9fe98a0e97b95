"""Calibration files: the shipped map, conversions, every kind of mistake rejected clearly, the guided wizard."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import yaml

from hardware import constants as C
from hardware.calibration import (
    Calibration,
    default_calibration,
    load_calibration,
    save_calibration,
    validate,
)
from hardware.emulator import ServoEmulator
from hardware.errors import CalibrationError
from hardware.serial_bus import BusConfig, SerialServoBus
from hardware.wizard import CalibrationWizard
from studio.cli.runs import advice


def test_shipped_calibration_is_valid_and_default(hand):
    cal = load_calibration(None, hand)
    assert cal.joint_names == hand.joint_names and cal.ids == list(range(1, 22))
    assert np.all(cal.lower >= hand.lower) and np.all(cal.upper <= hand.upper)
    assert np.all((cal.lower <= hand.rest_pose()) & (hand.rest_pose() <= cal.upper))
    assert np.allclose(cal.to_units(np.zeros(21)), 500)
    default = default_calibration(hand)  # the shipped file is the default map: every field of every joint
    assert [(j.name, j.servo_id, j.direction, j.zero) for j in cal.joints] == [
        (j.name, j.servo_id, j.direction, j.zero) for j in default.joints
    ]
    assert np.allclose(cal.lower, default.lower, atol=1e-6) and np.allclose(cal.upper, default.upper, atol=1e-6)


def test_conversion_round_trip(hand, rng):
    cal = default_calibration(hand)
    cal = Calibration(tuple(replace(j, direction=-1 if k % 2 else 1, zero=480 + k) for k, j in enumerate(cal.joints)))
    theta = rng.uniform(cal.lower, cal.upper, size=(50, 21))
    assert np.allclose(cal.to_rad(cal.to_units(theta)), theta)
    assert cal.to_units(np.full(21, np.radians(24.0)))[0] == pytest.approx(480 + 100)  # 1000 units = 240°
    assert cal.to_units(np.full(21, np.radians(24.0)))[1] == pytest.approx(481 - 100)


def test_save_load_round_trip(hand, tmp_path):
    cal = default_calibration(hand)
    save_calibration(cal, tmp_path / "c.yaml")
    back = load_calibration(tmp_path / "c.yaml", hand)
    assert back.ids == cal.ids and np.allclose(back.lower, cal.lower) and np.allclose(back.upper, cal.upper)


def _write(tmp_path, doc):
    p = tmp_path / "cal.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False) if not isinstance(doc, str) else doc)
    return p


def _doc(hand):
    cal = default_calibration(hand)
    return {
        "format": "shadow-studio-calibration",
        "version": 1,
        "joints": {
            j.name: {"id": j.servo_id, "direction": 1, "zero": 500, "lower": j.lower, "upper": j.upper}
            for j in cal.joints
        },
    }


MISTAKES = {
    "missing joint": (lambda d: d["joints"].pop("index_pip"), "not mapped to a servo: index_pip"),
    "unknown joint": (lambda d: d["joints"].__setitem__("sixth_finger", d["joints"]["wrist"] | {"id": 40}),
                      "not in the hand: sixth_finger"),
    "duplicate id": (lambda d: d["joints"]["index_pip"].__setitem__("id", 1), "servo ID 1 is used by wrist, index_pip"),
    "bad direction": (lambda d: d["joints"]["wrist"].__setitem__("direction", 0), "direction must be 1 or -1"),
    "beyond urdf": (lambda d: d["joints"]["ring_pip"].__setitem__("upper", 2.0), "outside the URDF limits"),
    "inverted limits": (lambda d: d["joints"]["ring_dip"].update(lower=0.5, upper=-0.5), "is not below the upper"),
    "zero off travel": (lambda d: d["joints"]["wrist"].__setitem__("zero", 1200), "outside the servo's 0..1000"),
    "beyond servo travel": (lambda d: d["joints"]["wrist"].__setitem__("zero", 200), "beyond the servo's 0..1000"),
    "id out of range": (lambda d: d["joints"]["wrist"].__setitem__("id", 254), "outside 0..253"),
    "missing key": (lambda d: d["joints"]["wrist"].pop("zero"), "missing keys ['zero']"),
    "not a number": (lambda d: d["joints"]["wrist"].__setitem__("lower", "low"), "must be numbers"),
    "wrong format": (lambda d: d.__setitem__("format", "other"), "not a calibration file"),
    "wrong version": (lambda d: d.__setitem__("version", 9), "unsupported calibration version 9"),
    "no joints": (lambda d: d.__setitem__("joints", []), "'joints' must map"),
}  # fmt: skip


@pytest.mark.parametrize("mistake", list(MISTAKES))
def test_each_mistake_is_rejected_clearly(hand, tmp_path, mistake):
    edit, message = MISTAKES[mistake]
    doc = _doc(hand)
    edit(doc)
    with pytest.raises(CalibrationError) as info:
        load_calibration(_write(tmp_path, doc), hand)
    assert message in str(info.value) and "cal.yaml" in str(info.value)


def test_not_yaml_and_missing_file(hand, tmp_path):
    with pytest.raises(CalibrationError, match="not valid YAML"):
        load_calibration(_write(tmp_path, "joints: [unclosed"), hand)
    with pytest.raises(FileNotFoundError, match="calibration file not found") as info:
        load_calibration(tmp_path / "nope.yaml", hand)
    assert isinstance(info.value, CalibrationError) and "shadow-studio" not in str(info.value)
    assert advice(info.value) == " (shadow-studio calibrate makes one)"  # what the command line adds


def test_validate_reorders_to_hand_order(hand):
    cal = default_calibration(hand)
    shuffled = Calibration(tuple(reversed(cal.joints)))
    assert validate(shuffled, hand).joint_names == hand.joint_names


def test_hand_box_is_the_soft_limits_within_the_urdfs_in_the_hands_order(hand):
    """Where the player stops each joint, in the hand's order: the shipped soft limits, a joint narrowed to its own
    limits, a joint set wider than the URDF held to the URDF's, a joint the calibration does not map left at it."""
    cal = default_calibration(hand)
    lo, hi = cal.hand_box(hand)
    assert np.allclose(lo, cal.lower) and np.allclose(hi, cal.upper) and np.all(lo >= hand.lower)
    pip, wrist = hand.joint_names.index("index_pip"), hand.joint_names.index("wrist")
    joints = tuple(replace(j, upper=0.3) if j.name == "index_pip" else replace(j, lower=-9.0) if j.name == "wrist"
                   else j for j in reversed(cal.joints) if j.name != "pinky_dip")  # fmt: skip
    lo, hi = replace(cal, joints=joints).hand_box(hand)
    assert hi[pip] == 0.3 and lo[wrist] == hand.lower[wrist]
    d = hand.joint_names.index("pinky_dip")
    assert (lo[d], hi[d]) == (hand.lower[d], hand.upper[d])


def test_wizard_jog_and_by_hand(hand):
    """Joint 1 is jogged with + / -; joint 2 is set by hand with reversed direction; the rest are skipped."""
    start = default_calibration(hand)
    with ServoEmulator(range(1, 22)) as emu, SerialServoBus(BusConfig(emu.port)) as bus:
        wiz = CalibrationWizard(bus, hand, start)
        wiz.cfg.move_s = 0.0
        assert "wrist" in wiz.prompt() and "zero" in wiz.prompt()
        assert wiz.execute("step 100") == "step 100 units"
        wiz.execute("+")  # zero at 600
        emu_wait(emu, 1, 600)
        wiz.execute("set")
        for _ in range(3):  # lower at 300
            wiz.execute("-")
        emu_wait(emu, 1, 300)
        wiz.execute("set")
        for _ in range(5):  # upper at 800
            wiz.execute("+")
        emu_wait(emu, 1, 800)
        assert "thumb_mcp_abd" in wiz.execute("set")
        assert "limp" in wiz.execute("free")
        for units in (450, 480, 200):  # zero, "lower" (units grow), "upper" (units shrink) -> direction -1
            emu.set_position(2, units)
            wiz.execute("")
        with pytest.raises(ValueError, match="unknown command"):
            wiz.execute("dance")
        while not wiz.finished:
            wiz.execute("skip")
        cal = wiz.result()
    w, t = cal.joints[0], cal.joints[1]
    assert (w.servo_id, w.direction, w.zero) == (1, 1, 600)
    assert w.lower == pytest.approx(-300 / C.UNITS_PER_RAD) and w.upper == pytest.approx(200 / C.UNITS_PER_RAD)
    assert (t.direction, t.zero) == (-1, 450) and t.upper == pytest.approx(250 / C.UNITS_PER_RAD)
    assert t.lower == 0.0  # recorded -0.126 rad lies below the URDF's 0: moved inside
    assert any("thumb_mcp_abd" in n for n in wiz.notes)
    assert cal.joints[5:] == start.joints[5:]


def emu_wait(emu, sid, units, timeout=1.0):
    import time

    t = time.perf_counter() + timeout
    while abs(emu.positions()[sid] - units) > 0.5:
        assert time.perf_counter() < t, f"servo {sid} never reached {units}"
        time.sleep(0.01)
