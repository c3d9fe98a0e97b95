"""`play` on a show file without hardware: the dry run (the built-in emulator) and its log, and what it checks and
says before anything moves (a show for another hand model, the joints the calibration's soft limits stop)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from hardware.calibration import default_calibration, load_calibration, save_calibration
from studio.cli.main import main


def tiny_show(hand, path, seconds):
    """A show of the wrist swinging gently (0.3 sin t rad) for ``seconds`` at 40 Hz, saved at ``path``."""
    from studio.motion.show import Show, save_show

    t = np.arange(0, seconds, 1 / 40)
    q = np.tile(hand.rest_pose(), (len(t), 1))
    q[:, 0] = 0.3 * np.sin(t)
    save_show(Show.from_samples(hand, t, q, title="tiny"), path)
    return path


def test_play_dry_run(hand, tmp_path, capsys):
    from studio.motion.show import Show, save_show

    t = np.arange(0, 0.5, 1 / 40)
    q = np.tile(hand.rest_pose(), (len(t), 1))
    q[:, 0] = 0.3 * t
    save_show(Show.from_samples(hand, t, q, title="tiny"), tmp_path / "tiny.json")
    log = tmp_path / "log.npz"
    assert main(["play", str(tmp_path / "tiny.json"), "--dry-run", "--log", str(log)]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "completed" in out and "torque held" in out and "jitter" in out
    assert re.search(rf"play:\s*\d+%.*\| \d+/{len(t)} ", captured.err), captured.err  # the bar counts the show's ticks
    saved = np.load(log)
    assert saved["sent"].shape == (len(t), 21) and len(saved["measured_rad"]) > 0
    assert main(["play", str(tmp_path / "tiny.json")]) == 2  # no port, no dry run: a one-line error
    assert "--port" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("format: nope\n")
    assert main(["play", str(tmp_path / "tiny.json"), "--dry-run", "--calibration", str(bad)]) == 2
    assert "not a calibration file" in capsys.readouterr().err
    assert load_calibration(None, hand).ids == list(range(1, 22))


def test_a_show_for_another_hand_is_refused_unless_forced(hand, tmp_path, capsys):
    from dataclasses import replace

    from studio.motion.show import load_show, save_show

    show = tmp_path / "other.json"
    save_show(replace(load_show(tiny_show(hand, show, 0.3)), hand_hash="0123456789abcdef"), show)
    assert main(["play", str(show), "--dry-run", "--log", str(tmp_path / "a.npz")]) == 2
    err = capsys.readouterr().err
    assert "planned for another hand model (hand 0123456789abcdef" in err and "pass --force" in err
    assert not (tmp_path / "a.npz").exists()
    assert main(["play", str(show), "--dry-run", "--log", str(tmp_path / "b.npz"), "--force"]) == 0
    assert "completed" in capsys.readouterr().out


def test_play_says_before_moving_which_joints_the_soft_limits_stop_and_the_player_stops_them_there(
    hand, tmp_path, capsys
):
    """A show that asks two joints beyond the shipped calibration's soft limits (which lie 0.05 rad inside the URDF's):
    `play` names them, farthest first, before anything moves, and the log shows the player stopped exactly those
    joints, by exactly as much as it said."""
    from hardware.show_checks import beyond_soft_limits
    from studio.motion.show import Show, save_show

    cal = load_calibration(None, hand)
    wrist, pip = hand.joint_names.index("wrist"), hand.joint_names.index("index_pip")
    t = np.arange(0, 1.0, 1 / 40)
    q = np.tile(hand.rest_pose(), (len(t), 1))
    q[:, wrist] = np.linspace(0.0, hand.upper[wrist] - 0.02, len(t))  # 0.03 rad beyond the soft upper limit
    q[:, pip] = np.linspace(q[0, pip], hand.lower[pip], len(t))  # 0.05 rad beyond the soft lower limit
    show = Show.from_samples(hand, t, q, title="to the limits")
    beyond = beyond_soft_limits(show.positions, show.joint_names, cal)
    assert [n for n, _ in beyond] == ["index_pip", "wrist"]
    assert [r for _, r in beyond] == pytest.approx([0.05, 0.03], abs=1e-6)
    save_show(show, tmp_path / "limits.json")
    log = tmp_path / "log.npz"
    assert main(["play", str(tmp_path / "limits.json"), "--dry-run", "--quiet", "--log", str(log)]) == 0
    out = capsys.readouterr().out.splitlines()
    note = next(x for x in out if x.startswith("note:"))
    assert out.index(note) < next(i for i, x in enumerate(out) if x.startswith("completed"))
    assert "2 joints beyond the calibration's soft limits (index_pip by 2.9°, wrist by 1.7°)" in note
    clipped = next(x for x in out if "ticks clipped:" in x)
    saved = np.load(log)
    names = [str(n) for n in saved["joint_names"]]
    over = np.abs(saved["requested"] - saved["sent"]).max(0)
    assert {names[j] for j in np.flatnonzero(over > 1e-6)} == {"index_pip", "wrist"}
    assert over[names.index("index_pip")] == pytest.approx(0.05, abs=1e-4)
    assert over[names.index("wrist")] == pytest.approx(0.03, abs=1e-4)
    held = int((np.abs(saved["requested"] - saved["sent"]).max(1) > 1e-6).sum())
    assert f"ticks clipped: {held} at the soft limits, 0 at the step limit" in clipped and held > 0
    assert main(["show-info", str(tmp_path / "limits.json")]) == 0  # says it too, without playing
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert last.startswith("limits:       the show asks 2 joints") and "(index_pip by 2.9°, wrist by 1.7°)" in last
    save_calibration(default_calibration(hand, margin=0.0), tmp_path / "wide.yaml")  # soft limits = the URDF's
    assert main(["show-info", str(tmp_path / "limits.json"), "--calibration", str(tmp_path / "wide.yaml")]) == 0
    assert capsys.readouterr().out.strip().splitlines()[-1].startswith("limits:       every pose within the")
