"""``shadow-studio project run`` and what it stands on: a project's keyframes on the show clock
(studio.project.show_timing) and run_project (studio.project.run): missing or stale keyframes
optimised, current ones never recomputed, the show planned, failures and cancels leaving the project as it was."""

from __future__ import annotations

import json
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest
from studio.assets import asset

from studio.cli.main import main
from studio.imitate.config import RefineConfig, SearchConfig, SequenceConfig
from studio.motion.show import load_show
from studio.project.project import Project, ProjectError
from studio.project.run import RunConfig, run_project
from studio.project.show_timing import ShowLayout, seams_out_of_reach
from studio.sim.hand import load_hand
from studio.targets.keyframes import KeyframeConfig
from studio.targets.video import DEFAULT_VIDEO

STILL = asset("targets/asl_o.jpeg")
TINY = ["--search-batch", "8", "--search-iterations", "20", "--next-batch", "8", "--next-iterations", "10",
        "--refine-steps", "30", "--refine-restarts", "2", "--candidates", "1", "--sweep-draws", "96",
        "--sweep-passes", "1", "--joint-generations", "10"]  # fmt: skip
TINY_SEQUENCE = SequenceConfig(
    first=SearchConfig(batch=8, iterations=20), next=SearchConfig(batch=8, iterations=10, lr=0.08),
    refine=RefineConfig(steps=30, restarts=2), candidates=1,
)  # fmt: skip


def run_cli(capsys, *argv: str) -> tuple[int, dict, str]:
    """``shadow-studio ARGV`` in this process: exit code, the JSON summary (last stdout line), stdout + stderr."""
    rc = main(list(argv))
    out = capsys.readouterr()
    lines = out.out.strip().splitlines()
    summary = json.loads(lines[-1]) if lines and lines[-1].startswith("{") else {}
    return rc, summary, out.out + out.err


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file of a project folder → its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def fake_results(project: Project, hand) -> None:
    """Every keyframe gets the rest pose as its (current) result: enough to time a show."""
    for kf in project.keyframes:
        project.set_result(kf.id, hand.rest_pose(), {"total": 0.5, "base": 0.2}, np.zeros((8, 8), np.uint8))


# ------------------------------------------------------------------------------------------ the show clock
def test_show_timing_plays_sources_one_after_another(tmp_path, hand):
    every_frame = KeyframeConfig(tau=1.0)  # each horse frame its own keyframe: one planner keyframe per frame
    project = Project.create(tmp_path / "two.shadow", sources=[STILL, DEFAULT_VIDEO], clustering=every_frame)
    with pytest.raises(ProjectError, match="no result for keyframe"):
        project.show_timing()
    fake_results(project, hand)
    layout = ShowLayout(still_hold_s=2.0, gap_s=1.5)
    timing = project.show_timing(layout)
    kf = timing.keyframes
    video_times = [f.time_s for f in project.frames if f.source == 1]
    video_ids = [k.id for k in project.keyframes if project.frames[k.representative].source == 1]
    # the still: reached at 0 and held for 2 s; then the horse at its own clock from 3.5 s to its end
    assert kf.times[:2].tolist() == [0.0, 2.0] and kf.hold[:2].all()
    start = 2.0 + 1.5
    assert kf.times[2:-1] == pytest.approx(start + np.array(video_times))
    end = min(video_times[-1] + 1 / project.state.video.hz, project.sources[1].duration_s)  # the GIF ends at 1.1 s
    assert kf.times[-1] == pytest.approx(start + end)
    assert timing.cluster.tolist() == [0, 0, *video_ids, video_ids[-1]]
    assert timing.frame[2:].tolist() == [*range(1, len(project.frames)), len(project.frames) - 1]
    assert kf.target[0] == "asl_o.jpeg#0" and kf.extra["title"] == "two"
    # the artist's time for the still moves it (the video follows it), a hold holds every appearance
    project.set_keyframe_time(0, 1.0)
    project.set_hold(video_ids[1], True)
    moved = project.show_timing(layout).keyframes
    assert moved.times[:3].tolist() == pytest.approx([1.0, 3.0, 4.5]) and moved.hold[3]
    # a video keyframe moved before the keyframe ahead of it is refused, naming it
    project.set_keyframe_time(video_ids[2], 0.5)
    with pytest.raises(ProjectError, match=f"keyframe {video_ids[2]} would be at 0.500 s"):
        project.show_timing(layout)
    # a stale result cannot be timed either
    project.set_keyframe_time(video_ids[2], None)
    project.set_weights(w_iou=0.5)
    with pytest.raises(ProjectError, match="stale result"):
        project.show_timing(layout)


def test_a_move_between_sources_too_fast_for_the_servos_names_one_keyframe_to_optimise_again(tmp_path, hand):
    """A run keeps each keyframe within reach of its own source's: the move from the still to the horse is checked
    after. Too fast for the servos, it names the keyframe every neighbour leaves room for (the still, held alone;
    the horse's first keyframe is tied to the next), or the horse's when only the horse was optimised; a far move
    within the horse is its own chain's, and a move that fits names nothing."""
    project = Project.create(tmp_path / "two.shadow", sources=[STILL, DEFAULT_VIDEO])
    fake_results(project, hand)
    still = [kf.id for kf in project.keyframes if project.frames[kf.representative].source == 0]
    horse = [kf.id for kf in project.keyframes if project.frames[kf.representative].source == 1]
    assert len(still) == 1 and len(horse) >= 2
    layout, every = ShowLayout(gap_s=0.2), [kf.id for kf in project.keyframes]
    assert seams_out_of_reach(project.state, every, layout) == []
    j = int(np.argmax(hand.upper - hand.lower))  # the joint with the widest range: end to end takes over 0.2 s
    far, near = hand.rest_pose().copy(), hand.rest_pose().copy()
    far[j], near[j] = hand.upper[j], hand.lower[j]
    empty = np.zeros((8, 8), np.uint8)
    project.set_result(still[0], near, {"total": 0.5, "base": 0.2}, empty)
    for k in horse:
        project.set_result(k, far, {"total": 0.5, "base": 0.2}, empty)
    assert seams_out_of_reach(project.state, every, layout) == still
    assert seams_out_of_reach(project.state, horse, layout) == horse[:1]
    assert seams_out_of_reach(project.state, still, ShowLayout(gap_s=60.0)) == []  # a minute is time enough
    project.set_result(still[0], far, {"total": 0.5, "base": 0.2}, empty)
    project.set_result(horse[1], near, {"total": 0.5, "base": 0.2}, empty)
    assert seams_out_of_reach(project.state, every, layout) == []  # within the horse: its chain's reach


# ------------------------------------------------------------------------------------------ project run
@pytest.mark.slow
def test_run_sets_results_and_a_show_and_a_second_run_does_nothing(tmp_path, capsys):
    path = tmp_path / "o.shadow"
    Project.create(path, sources=[STILL])
    rc, summary, text = run_cli(capsys, "project", "run", str(path), *TINY)
    assert rc == 0, text
    assert summary["keyframes_optimised"] == [0] and summary["keyframes_skipped"] == []
    assert summary["show"] == "planned" and summary["show_seconds"] == pytest.approx(2.0)
    assert summary["clip"] is None and summary["seconds"] > 0  # CLIP off: no weights here
    project = Project.open(path)
    assert project.pending_keyframes() == [] and not project.is_show_stale()
    result = project.results[0]
    assert result.collision_free and 0 <= result.loss["iou_loss"] < 1 and result.seconds > 0
    out = project.export_show(tmp_path / "show.json")
    load_show(out)  # validates
    before = snapshot(path)
    rc, again, text = run_cli(capsys, "project", "run", str(path), *TINY)
    assert rc == 0, text
    assert again["keyframes_optimised"] == [] and again["keyframes_skipped"] == [0] and again["show"] == "current"
    assert "nothing to do" in again["message"]
    assert snapshot(path) == before  # not one byte rewritten


@pytest.mark.slow
def test_a_stale_keyframe_is_recomputed_and_the_show_replanned(tmp_path, capsys):
    path = tmp_path / "o.shadow"
    Project.create(path, sources=[STILL])
    assert run_cli(capsys, "project", "run", str(path), *TINY)[0] == 0
    project = Project.open(path)
    old = project.results[0]
    project.set_weights(w_iou=0.5)
    assert project.stale_keyframes() == [0] and project.is_show_stale()
    rc, summary, text = run_cli(capsys, "project", "run", str(path), *TINY)
    assert rc == 0, text
    assert summary["keyframes_optimised"] == [0] and summary["show"] == "planned"
    project = Project.open(path)
    assert project.stale_keyframes() == [] and not project.is_show_stale()
    assert project.results[0].inputs != old.inputs


def test_a_missing_source_does_not_block_the_run(tmp_path, capsys):
    """Every frame's mask is stored in the project: a deleted source is warned about, the run goes on."""
    src = tmp_path / "o.jpeg"
    shutil.copy(STILL, src)
    path = tmp_path / "o.shadow"
    Project.create(path, sources=[src])
    src.unlink()
    rc, summary, text = run_cli(capsys, "project", "run", str(path), *TINY)
    assert rc == 0, text
    assert summary["keyframes_optimised"] == [0] and summary["show"] == "planned" and "Traceback" not in text
    assert Project.open(path).missing_sources[0].absolute == str(src)


@pytest.mark.slow
def test_too_fast_without_allow_late_keeps_the_keyframes_and_lists_the_transitions(tmp_path, capsys):
    path = tmp_path / "horse.shadow"
    project = Project.create(path, sources=[DEFAULT_VIDEO])
    ids = [kf.id for kf in project.keyframes]
    free = "--no-keep-clock"  # poses chosen without the servos' clock (the paper's way): transitions too fast
    rc, summary, text = run_cli(capsys, "project", "run", str(path), *TINY, free)
    assert rc == 1, text
    assert summary["keyframes_optimised"] == ids and summary["show"] is None and summary["late_transitions"]
    assert "too fast:" in text and "allow late" in summary["message"] and "--allow-late" in text
    assert summary["transitions"] == len(ids) - 1
    project = Project.open(path)
    assert project.pending_keyframes() == [] and project.show is None
    rc, summary, text = run_cli(capsys, "project", "run", str(path), *TINY, free, "--allow-late")
    assert rc == 0, text
    assert summary["keyframes_optimised"] == [] and summary["keyframes_skipped"] == ids
    assert summary["show"] == "planned" and summary["late_transitions"]
    late = summary["late_transitions"][0]
    assert late["needed_s"] > late["given_s"] and "late:" in text
    assert Project.open(path).show.duration > project.show_timing().end_s  # stretched: longer than the video
    # the studio's default keeps every keyframe within the servos' reach at the clock: no late transition, a show
    # exactly as long as the sampled video
    kept = tmp_path / "kept.shadow"
    Project.create(kept, sources=[DEFAULT_VIDEO])
    rc, summary, text = run_cli(capsys, "project", "run", str(kept), *TINY)
    assert rc == 0 and summary["show"] == "planned" and summary["late_transitions"] == [], text
    assert summary["show_seconds"] == pytest.approx(Project.open(kept).show_timing().end_s)


@pytest.mark.slow
def test_a_still_then_a_video_on_a_short_gap_plays_without_a_late_transition(tmp_path, capsys):
    """0.3 s from the still to the horse: each source's keyframes are kept within their own reach, and the move
    between them is checked after and mended (the still optimised again within reach of the horse's first pose),
    so the show plans without --allow-late and lasts exactly as long as the clock. A run stopped while it mends
    leaves the still to optimise again, and resumed it makes the same poses and show."""
    path, cut = tmp_path / "two.shadow", tmp_path / "cut.shadow"
    Project.create(path, sources=[STILL, DEFAULT_VIDEO]).set_roll(0.0)
    shutil.copytree(path, cut)
    argv = ["project", "run", str(path), *TINY, "--gap-s", "0.3"]
    rc, summary, text = run_cli(capsys, *argv)
    assert rc == 0 and summary["show"] == "planned" and summary["late_transitions"] == [], text
    assert "again: its move to or from another source was too fast for the servos" in text  # said, not silent
    assert summary["show_seconds"] == pytest.approx(Project.open(path).show_timing(ShowLayout(gap_s=0.3)).end_s)
    # stopped while the still is optimised again: it stays stale (owed "again"), and the same command resumes the
    # run to the same poses and show
    from studio.cli.main import build_parser
    from studio.cli.run_flags import run_config_from_args

    cfg = run_config_from_args(build_parser().parse_args(argv))
    cancel = threading.Event()
    report = run_project(Project.open(cut), cfg, cancel=cancel,
                         on_job=lambda job, what: " again: " in what and cancel.set())  # fmt: skip
    assert report.cancelled, report.message
    stopped = Project.open(cut)
    still = stopped.keyframes[0].id
    assert stopped.results[still].awaits == "again" and stopped.pending_keyframes() == [still]
    rc, resumed, text = run_cli(capsys, *[str(cut) if a == str(path) else a for a in argv])
    assert rc == 0 and resumed["late_transitions"] == [] and resumed["keyframes_optimised"] == [still], text
    joints = load_hand().joint_names
    done, want = Project.open(cut), Project.open(path)
    assert all(np.array_equal(done.results[k].theta(joints), want.results[k].theta(joints)) for k in want.results)
    assert not any(r.awaits for r in done.results.values()) and done.show.duration == want.show.duration


def test_a_cancel_keeps_only_the_keyframes_finished_before_it(tmp_path):
    project = Project.create(tmp_path / "two.shadow", sources=[STILL, DEFAULT_VIDEO])
    cancel = threading.Event()
    submitted = []

    def on_job(job, what):
        if what.startswith("keyframe"):  # (the mount roll is chosen first)
            submitted.append(what)
        if len(submitted) == 2:  # the first keyframe is done and saved; cancel the second as it starts
            cancel.set()

    report = run_project(project, RunConfig(sequence=TINY_SEQUENCE), cancel=cancel, on_job=on_job)
    assert report.cancelled and not report.ok and report.show is None
    assert report.optimised == [0] and "keyframe 1 cancelled" in report.message
    reopened = Project.open(project.path)
    assert set(reopened.results) == {0} and reopened.show is None
    assert reopened.pending_keyframes() == [kf.id for kf in reopened.keyframes[1:]]
