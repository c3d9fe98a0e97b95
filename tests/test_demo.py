"""``shadow-studio demo --out DIR`` end to end in a subprocess (small budgets): the project, the show file, the show
played on the emulator and the review recording read back; a second run reuses the project."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hardware.calibration import load_calibration
from hardware.player import PlayerConfig
from hardware.safety import SafetyConfig
from hardware.show_checks import beyond_soft_limits
from studio.cli.main import main
from studio.motion.show import load_show
from studio.project.project import Project
from studio.review.readback import read_recording, scalar_series
from studio.sim.hand import load_hand

CLI = [sys.executable, "-m", "studio.cli.main"]
SMALL = ["--search-batch", "8", "--search-iterations", "30", "--next-batch", "8", "--next-iterations", "15",
         "--refine-steps", "40", "--refine-restarts", "2", "--candidates", "1", "--quiet",
         "--sweep-draws", "96", "--sweep-passes", "1", "--joint-generations", "10"]  # fmt: skip

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="the emulator needs POSIX pseudo-terminals")


def demo(out: Path, *extra: str) -> tuple[dict, str]:
    """Run the demo; its JSON summary (the last stdout line) and all it printed."""
    done = subprocess.run([*CLI, "demo", "--out", str(out), *SMALL, *extra], capture_output=True, text=True,
                          timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stdout + done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1]), done.stdout + done.stderr


def entity(recording: dict, path: str) -> dict:
    return recording.get(path) or recording["/" + path]


def series(recording: dict, path: str, timeline: str) -> np.ndarray:
    """``(n, 2)`` (time, value) rows of a Scalars entity (:func:`scalar_series`: seconds on show_time)."""
    key = path if path in recording else "/" + path
    return np.array(scalar_series(recording, key, timeline), dtype=float)


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    summary, text = demo(out)
    return out, summary, text


@pytest.mark.slow
def test_demo_writes_the_project_the_show_and_plays_it(first_run, capsys):
    out, summary, text = first_run
    assert {"project", "show", "review", "keyframes", "played", "seconds"} <= set(summary)
    assert summary["played"] is True and summary["playback"]["reason"] == "completed"
    assert summary["fresh_project"] is True and summary["no_clip"] is True and summary["seconds"] > 0
    project = Project.open(summary["project"])
    assert Path(summary["project"]) == out / "demo.shadow"
    assert [s.kind for s in project.sources] == ["still", "video"]
    assert summary["keyframes"] == len(project.keyframes) >= 2
    assert summary["keyframes_optimised"] == [kf.id for kf in project.keyframes]
    assert project.pending_keyframes() == [] and project.show is not None and not project.is_show_stale()
    # every keyframe kept within the servos' reach at the show's clock: nothing to stretch, and the show lasts the
    # still's hold, the gap and the horse exactly
    assert summary["late_transitions"] == [] and "late:" not in text
    assert project.show.duration == pytest.approx(project.show_timing().end_s)
    show = load_show(summary["show"])
    assert Path(summary["show"]) == out / "show.json"
    assert show.duration == pytest.approx(project.show.duration)
    assert main(["validate", summary["show"]]) == 0
    capsys.readouterr()
    # the joints the shipped calibration's soft limits stop, said before playing (the planner works to the URDF's)
    beyond = beyond_soft_limits(show.positions, show.joint_names, load_calibration(None, load_hand()))
    assert summary["playback"]["beyond_soft_limits_deg"] == {n: round(np.degrees(r), 2) for n, r in beyond}
    assert ("note: the show asks" in text) == bool(beyond)


@pytest.mark.slow
def test_demo_review_holds_every_stage_and_the_played_show(first_run):
    out, summary, _ = first_run
    assert Path(summary["review"]) == out / "review.rrd"
    rec = read_recording(out / "review.rrd")
    project = Project.open(summary["project"])
    show = load_show(summary["show"])
    # optimisation: every keyframe job's best loss on opt_step, then the keyframes refined together's
    losses = [p for p in rec if p.lstrip("/").startswith("loss/job") and "opt_step" in rec[p]["timelines"]]
    jobs = {p.split("/")[2] for p in losses}
    assert len({j for j in jobs if "imitate_keyframes" in j}) == len(project.keyframes) and "job1_choose_roll" in jobs
    assert f"job{len(project.keyframes) + 2}_imitate_together" in jobs
    # frames: every frame's target and expressive mask, and the keyframe it plays, on frame
    for path in ("images/target", "images/expressive", "frames/keyframe"):
        assert "frame" in entity(rec, path)["timelines"]
    # and the frames' images on show_time, where the show plays each: one row a frame on each timeline
    assert "show_time" in entity(rec, "images/target")["timelines"]
    assert entity(rec, "images/target")["rows"] == 2 * len(project.frames)
    # the show on show_time: the backdrop carrying its shadow (and the hand's pose)
    assert "show_time" in entity(rec, "world/backdrop")["timelines"]
    assert any(p.lstrip("/").startswith("world/pose") and "show_time" in rec[p]["timelines"] for p in rec)
    # the played show: commanded vs measured per joint, the commanded angles being the show's within the servos'
    # soft limits (the player clips to the calibration's, a margin inside the URDF's that the planner keeps)
    cal = load_calibration(None, load_hand())
    assert cal.joint_names == show.joint_names
    step = SafetyConfig().max_speed_rad_s / PlayerConfig().rate_hz  # the player's largest move in one tick, rad
    for j, name in enumerate(show.joint_names):
        commanded = series(rec, f"servo/{name}/commanded", "show_time")
        measured = series(rec, f"servo/{name}/measured", "show_time")
        assert len(commanded) == summary["playback"]["ticks"] and len(measured) > 10
        t = commanded[:, 0]
        during = np.flatnonzero((t >= 0) & (t <= show.duration))
        planned = np.clip(show.sample(t[during])[:, j], cal.lower[j], cal.upper[j])
        off = np.abs(commanded[during, 1] - planned) > 1e-6
        # ... except after a tick the OS stalled past (a loaded machine): the player skips to the current tick and
        # catches up at the step limit, each such command exactly one step from the one before, toward the plan
        caught_up = np.abs(commanded[during[off], 1] - commanded[during[off] - 1, 1])
        assert off.mean() < 0.1 and np.allclose(caught_up, step, atol=1e-9), (name, caught_up, step)
        # the emulated servos follow: each read-back lies within the commands of the quarter second before it
        for tm, q in measured:
            recent = commanded[(t >= tm - 0.25) & (t <= tm + 1e-6), 1]
            assert recent.min() - 0.02 <= q <= recent.max() + 0.02, (name, tm, q, recent)


@pytest.mark.slow
def test_demo_again_reuses_the_project(first_run):
    out, first, _ = first_run
    summary, text = demo(out)
    assert "reusing" in text and summary["fresh_project"] is False
    assert summary["keyframes_optimised"] == [] and summary["keyframes_skipped"] == first["keyframes_optimised"]
    assert summary["played"] is True and summary["late_transitions"] == first["late_transitions"]
    assert load_show(summary["show"]).duration == pytest.approx(load_show(first["show"]).duration)


@pytest.mark.parametrize("flag", ["--fresh", "--force"])
def test_demo_fresh_removes_only_a_project(tmp_path, capsys, flag):
    """`demo --fresh` (as on imitate-video; `--force` its old name) never deletes a folder that is not a project."""
    mine = tmp_path / "demo.shadow"
    mine.mkdir()
    (mine / "notes.txt").write_text("my own file")
    assert main(["demo", "--out", str(tmp_path), flag]) == 2
    err = capsys.readouterr().err
    assert "is not a project folder; --fresh removes only a project" in err and "Traceback" not in err
    assert (mine / "notes.txt").read_text() == "my own file"
