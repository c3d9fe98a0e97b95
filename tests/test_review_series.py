"""What a review logs whole, each version replacing the last (studio.review.series), read back from real recordings:
a frame's loss logged again after an edit is a new version that hides the old; the keyframes' and the show's log
lines are not repeated by every edit; after the keyframes or the show change, no time shows what an earlier log put
there. What Rerun's own web viewer draws of them: tests/test_review_viewer.py."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from studio.motion.plan import Keyframes, plan_show
from studio.review.blueprint import time_column
from studio.review.frames import KeyframeReview
from studio.review.readback import ordered_rows, read_recording, scalar_series, shown_series
from studio.review.recording import ProjectRecording
from studio.review.rig3d import RigReview, show_instants
from studio.review.series import VersionedLog, series_colour
from studio.sim.hand import load_hand

N = 10
MASKS = np.zeros((N, 16, 16), np.uint8)
MASKS[:, 4:12, 4:12] = 1
BEFORE = [KeyframeReview(0, 0, tuple(range(N)), loss={"total": 0.2, "base": 0.5})]  # one keyframe plays every frame
AFTER = [  # the artist split it: the first half's keyframe scored 0.8, the second half's has no total
    KeyframeReview(0, 0, tuple(range(5)), loss={"total": 0.8, "base": 0.5}),
    KeyframeReview(1, 5, tuple(range(5, N)), loss={"base": 0.5, "total": float("nan")}),
]


def edited(path: Path, show_times: np.ndarray | None = None) -> dict:
    """A recording of the frames logged before and after the edit (the Review panel logs the project again)."""
    with ProjectRecording(path=path) as review:
        review.log_frames(MASKS, MASKS, BEFORE)
        review.log_frames(MASKS, MASKS, AFTER, show_times=show_times)
    return read_recording(path)


def series_style(rec: dict, entity: str) -> tuple[list, list]:
    """The legend names and colours a series' static SeriesLines give."""
    names, colours = [], []
    for batch in rec[entity]["batches"]:
        if "SeriesLines:names" in batch.schema.names:
            names += batch.column("SeriesLines:names").to_pylist()[0]
            colours += batch.column("SeriesLines:colors").to_pylist()[0]
    return names, colours


def test_a_series_sent_again_hides_its_last_version_and_keeps_its_name_and_colour(tmp_path):
    rec = edited(tmp_path / "r.rrd")
    shown = shown_series(rec, "/loss/frame/total")
    assert shown == "/loss/frame/total/v1"
    assert scalar_series(rec, shown, "frame") == [(k, 0.8) for k in range(5)]  # the second half has no total now
    assert "Scalars:scalars" in rec["/loss/frame/total"]["static_columns"]  # the first version: shadowed
    assert scalar_series(rec, "/loss/frame/total", "frame") == [(k, 0.2) for k in range(N)]  # ... its rows kept
    assert series_style(rec, "/loss/frame/total") == series_style(rec, shown)
    names, colours = series_style(rec, shown)
    r, g, b = series_colour("loss/frame/total")
    assert names == ["total"] and colours == [(r << 24) | (g << 16) | (b << 8) | 0xFF]
    assert series_colour("loss/frame/total") != series_colour("loss/frame/base")  # two components, two colours
    base = shown_series(rec, "/loss/frame/base")
    assert scalar_series(rec, base, "frame") == [(k, 0.5) for k in range(N)]
    keyframe = shown_series(rec, "/frames/keyframe")
    assert [v for _, v in scalar_series(rec, keyframe, "frame")] == [0] * 5 + [1] * 5


def test_the_keyframe_of_each_frame_is_a_dot_per_frame_and_the_losses_lines(tmp_path):
    rec = edited(tmp_path / "r.rrd")
    keyframe = shown_series(rec, "/frames/keyframe")

    def styles(entity: str) -> set[str]:  # the archetypes of its static style rows
        return {n.partition(":")[0] for b in rec[entity]["batches"] for n in b.schema.names if n.startswith("Series")}

    assert styles(keyframe) == {"SeriesPoints"}  # a step drawn as a line would slope between keyframes 0 and 1
    assert styles(shown_series(rec, "/loss/frame/total")) == {"SeriesLines"}


def test_a_series_with_nothing_left_is_hidden(tmp_path):
    with ProjectRecording(path=tmp_path / "r.rrd") as review:
        versions = VersionedLog(review.rec)
        assert versions.scalars("loss/x", [], np.zeros(0)) is None and versions.shown("loss/x") is None
        frames = np.arange(3)
        assert versions.scalars("loss/x", [time_column("frame", frames)], np.ones(3)) == "loss/x/v1"
        assert versions.scalars("loss/x", [], np.zeros(0)) is None and versions.shown("loss/x") is None
    rec = read_recording(tmp_path / "r.rrd")
    assert shown_series(rec, "/loss/x") is None and "Scalars:scalars" in rec["/loss/x/v1"]["static_columns"]


def test_the_keyframe_and_show_lines_are_those_of_the_last_log(tmp_path):
    show = plan_show(load_hand(), Keyframes.at([0.0, 0.4], np.zeros((2, 21))), title="first").show
    with ProjectRecording(path=tmp_path / "r.rrd") as review:
        review.log_frames(MASKS, MASKS, BEFORE)
        review.log_show(show)
        review.log_frames(MASKS, MASKS, AFTER)
        review.log_show(replace(show, title="second"))
    rec = read_recording(tmp_path / "r.rrd")

    def lines(path: str) -> list[str]:
        entity = shown_series(rec, path, "TextLog:text")
        return [text[0] for batch in rec[entity]["batches"] if "TextLog:text" in batch.schema.names
                for text in batch.column("TextLog:text").to_pylist()]  # fmt: skip

    keyframes = lines("/log/keyframes")
    assert len(keyframes) == 2 and "keyframe 0 (id 0)" in keyframes[0] and "plays 5 frames" in keyframes[0]
    assert "keyframe 1 (id 1): frame 5" in keyframes[1] and "no result yet" in keyframes[1]
    assert lines("/log/show")[0].startswith("show 'second'") and len(lines("/log/show")) == 1 + len(show.keyframes)
    assert "TextLog:text" in rec["/log/keyframes"]["static_columns"]  # the first log's lines: hidden


def test_a_shorter_show_ends_on_its_last_pose_and_the_same_show_is_not_logged_again(tmp_path):
    hand = load_hand()
    poses = np.repeat(hand.rest_pose()[None], 3, axis=0)
    poses[:, 0] = [0.0, 0.3, -0.3]  # the wrist turns: collision-free, within the servos' reach
    longer = plan_show(hand, Keyframes.at([0.0, 1.0, 3.0], poses), title="longer").show
    shorter = plan_show(hand, Keyframes.at([0.0, 1.0], poses[:2]), title="shorter").show
    joint = f"/world/pose/{hand.joint_names[0]}"
    with ProjectRecording(path=tmp_path / "r.rrd") as review:
        review.log_show(longer)
        review.log_show(shorter)
        review.log_show(shorter)  # unchanged: nothing is logged
    rec = read_recording(tmp_path / "r.rrd")
    rows = ordered_rows(rec, joint, "show_time")
    count = len(rows)
    # show time (ns) → the transform logged last at that time (latest-at's answer)
    latest = {r["t"]: tuple(np.round(r["Transform3D:quaternion"][0], 9)) for r in rows}
    logged = np.unique(np.round(np.r_[longer.times, show_instants(longer, RigReview().show_hz)], 9))
    assert count == len(longer.times) + len(shorter.times) + int(np.sum(logged > shorter.times[-1] + 1e-9))
    end = latest[int(round(shorter.times[-1] * 1e9))]
    beyond = [t for t in latest if t > shorter.times[-1] * 1e9 + 1]
    assert beyond and all(latest[t] == end for t in beyond)  # the longer show's later poses no longer show
    before_end = int(round(shorter.times[len(shorter.times) // 2] * 1e9))
    assert latest[before_end] != end  # (the joint does move: the check above can fail)
    backdrops = [t for b in rec["/world/backdrop"]["batches"] if "show_time" in b.schema.names
                 for t in b.column("show_time").cast("int64").to_pylist()]  # fmt: skip
    assert max(backdrops) == int(round(longer.times[-1] * 1e9))  # the bare end of the longer show is covered too


def latest_at(rec: dict, entity: str, frame: int) -> dict | None:
    """The row of ``entity`` that Rerun shows at ``frame``: the one logged last at the latest frame ≤ it."""
    before = [r for r in ordered_rows(rec, entity, "frame") if r["t"] <= frame]
    return before[-1] if before else None


def test_after_the_keyframes_change_every_frame_shows_its_own_keyframe(tmp_path):
    def shadow(k: int) -> np.ndarray:
        out = np.zeros((16, 16), np.uint8)
        out[k, :] = 1
        return out

    first = [
        KeyframeReview(0, 0, tuple(range(5)), shadow=shadow(0)),
        KeyframeReview(1, 5, (5, 6, 7, 8, 9), theta=np.r_[0.3, np.zeros(20)], shadow=shadow(1)),  # the wrist turned
    ]
    then = [
        KeyframeReview(0, 0, (0, 1, 2), shadow=shadow(0)),
        KeyframeReview(2, 3, tuple(range(3, N)), theta=np.r_[-0.3, np.zeros(20)], shadow=shadow(2)),
    ]
    with ProjectRecording(path=tmp_path / "r.rrd") as review:
        review.log_frames(MASKS, MASKS, first)
        review.log_frames(MASKS, MASKS, then)  # "Apply τ": frame 5 no longer starts a keyframe
        review.log_frames(MASKS[:6], MASKS[:6], [replace(then[1], members=(3, 4, 5))])  # frames 6-9 are gone
    rec = read_recording(tmp_path / "r.rrd")

    def shown(frame: int) -> int | None:  # the row of the rendered shadow Rerun shows: which keyframe's
        row = latest_at(rec, "/images/rendered", frame)
        if row is None or not row.get("Image:buffer"):
            return None
        image = np.asarray(row["Image:buffer"][0], np.uint8)
        return int(np.argmin(image.reshape(16, 16, -1)[..., 0].min(axis=1)))  # the dark row

    assert [shown(k) for k in range(6)] == [None, None, None, 2, 2, 2]  # frames 0-2 are in no keyframe now
    assert all(latest_at(rec, "/images/target", k).get("Image:buffer") is None for k in range(6, N))  # cleared
    assert latest_at(rec, "/images/target", 5).get("Image:buffer")
    wrist = {k: latest_at(rec, "/world/pose/wrist", k)["Transform3D:quaternion"] for k in (0, 3, 5, 8)}
    assert wrist[3] == wrist[5] != wrist[0]  # keyframe 2's turned wrist, not keyframe 1's other turn at frame 5
    assert wrist[8] == wrist[0]  # frames 6-9 are gone: the hand rests there, as in frames 0-2 (in no keyframe)


def test_frames_that_come_back_show_their_keyframe_again(tmp_path):
    one = [KeyframeReview(0, 0, tuple(range(N)), theta=np.r_[0.3, np.zeros(20)], shadow=MASKS[0])]
    with ProjectRecording(path=tmp_path / "r.rrd") as review:
        review.log_frames(MASKS, MASKS, one)
        review.log_frames(MASKS[:5], MASKS[:5], [replace(one[0], members=tuple(range(5)))])  # frames 5-9 gone
        review.log_frames(MASKS, MASKS, one)  # and back (an undo)
    rec = read_recording(tmp_path / "r.rrd")
    for k in range(N):
        assert latest_at(rec, "/images/rendered", k).get("Image:buffer"), k  # its keyframe's shadow, not cleared
        assert (
            latest_at(rec, "/world/pose/wrist", k)["Transform3D:quaternion"]
            == (latest_at(rec, "/world/pose/wrist", 0)["Transform3D:quaternion"])
        ), k  # its keyframe's turned wrist, not the rest pose the gone frames were given


def test_a_frame_image_is_logged_again_only_when_it_changed(tmp_path):
    edited_masks = MASKS.copy()
    edited_masks[7, 0, 0] = 1  # one frame's target edited (the expressive mask is the same array here)
    with ProjectRecording(path=tmp_path / "r.rrd") as review:
        review.log_frames(MASKS, MASKS, BEFORE)
        review.log_frames(MASKS, MASKS, BEFORE)  # nothing changed
        review.log_frames(edited_masks, edited_masks, BEFORE)
    rec = read_recording(tmp_path / "r.rrd")
    for entity in ("/images/target", "/images/expressive"):
        rows = ordered_rows(rec, entity, "frame")
        assert sorted(r["t"] for r in rows) == sorted([*range(N), 7]), entity  # frame 7 twice, every other frame once
        assert latest_at(rec, entity, 7)["Image:buffer"] != rows[0]["Image:buffer"]  # the edited one shows


def test_a_project_logged_again_unchanged_adds_no_images_and_no_show(tmp_path):
    from preview_support import give_results, horse, plan

    hand = load_hand()
    project = horse(tmp_path)
    give_results(project, hand)
    plan(project, hand)
    counted = ("/images/target", "/images/expressive", "/images/rendered", "/world/backdrop", "/world/pose/wrist")

    def rows(path: Path) -> dict[str, int]:
        rec = read_recording(path)
        return {e: len(ordered_rows(rec, e, "frame")) + len(ordered_rows(rec, e, "show_time")) for e in counted}

    with ProjectRecording(path=tmp_path / "once.rrd") as review:
        review.log_project(project)
    with ProjectRecording(path=tmp_path / "twice.rrd") as review:
        review.log_project(project)
        review.log_project(project)  # what the notebook does after an edit that changed nothing shown
    once, twice = rows(tmp_path / "once.rrd"), rows(tmp_path / "twice.rrd")
    assert all(once.values()) and twice == once  # not a row more
    rec = read_recording(tmp_path / "twice.rrd")
    for path in ("/loss/frame/total", "/frames/keyframe", "/log/keyframes", "/log/show"):  # no second version
        assert not [e for e in rec if e.startswith(f"{path}/v")], path


def test_the_losses_follow_the_show_on_show_time(tmp_path):
    show_times = np.linspace(0.0, 2.25, N) + np.r_[np.zeros(5), np.full(5, 0.5)]  # a stretched transition at 5
    rec = edited(tmp_path / "r.rrd", show_times)
    total = shown_series(rec, "/loss/frame/total")
    rows = np.array(scalar_series(rec, total, "show_time"))  # (frames, 2): show time, value (pytest ≥ 9.2's approx
    assert rows == pytest.approx(np.array([(t, 0.8) for t in show_times[:5]]))  # compares no nested lists)
    keyframe = shown_series(rec, "/frames/keyframe")
    rows = np.array(scalar_series(rec, keyframe, "show_time"))
    assert rows == pytest.approx(np.array(list(zip(show_times, [0] * 5 + [1] * 5))))
    with pytest.raises(ValueError, match="show times"):
        ProjectRecording(path=tmp_path / "bad.rrd").log_frames(MASKS, MASKS, AFTER, show_times=np.zeros(3))


def test_a_second_playback_replaces_the_first(tmp_path):
    def played(offset: float) -> SimpleNamespace:  # what hardware.playback_log.PlaybackResult carries
        t = np.arange(8) / 40
        return SimpleNamespace(
            joint_names=["wrist", "thumb_cmc"], t=t, sent=np.stack([t + offset, t - offset], axis=1), ramp_ticks=2,
            measured_t=t[::2], measured_joint=np.zeros(4, int), measured_rad=t[::2] + offset, reason="completed",
            message="done",
        )  # fmt: skip

    with ProjectRecording(path=tmp_path / "r.rrd") as review:
        review.log_playback(played(0.0), rate_hz=40)
        review.log_playback(played(1.0), rate_hz=40)
    rec = read_recording(tmp_path / "r.rrd")
    commanded = shown_series(rec, "/servo/wrist/commanded")
    assert commanded == "/servo/wrist/commanded/v1"
    assert [v for _, v in scalar_series(rec, commanded, "play_time")] == pytest.approx(np.arange(8) / 40 + 1.0)
    assert [v for _, v in scalar_series(rec, shown_series(rec, "/servo/wrist/measured"), "show_time")] == (
        pytest.approx(np.arange(0, 8, 2) / 40 + 1.0)
    )
    assert shown_series(rec, "/servo/thumb_cmc/measured") is None  # never read back in either playback


def test_a_later_job_follows_every_earlier_job_on_opt_step(tmp_path):
    from studio.jobs import Job, JobQueue

    def engine(steps: int, shade: int):
        def run(report, cancel):  # a search, then a refinement, reporting as the engine does
            for step in range(steps + 1):
                report("search", step, steps, 1.0 / (1 + step), np.full((4, 4), shade, np.uint8))
            report("refine", 1, 1, 0.01)
            return "done"

        return run

    told: list[tuple[int, int]] = []
    with ProjectRecording(path=tmp_path / "r.rrd") as review, JobQueue() as queue:
        queue.subscribe(review.job_progress(on_step=lambda event, step: told.append((event.job_id, step))))
        assert queue.run(Job("imitate-keyframe", engine(30, 1))).result == "done"
        assert queue.run(Job("imitate-keyframe", engine(5, 0))).result == "done"  # shorter, after it
    rec = read_recording(tmp_path / "r.rrd")

    def steps(job: int) -> list[int]:  # every opt_step a job's losses were drawn at (search, refine, apply)
        return sorted(t for e in rec if e.startswith(f"/loss/job{job}_") for t, _ in scalar_series(rec, e))

    first, second = steps(1), steps(2)
    assert first[:31] == list(range(31)) and len(first) == 33  # its stages follow one another
    assert second == list(range(first[-1] + 1, first[-1] + 9))  # one past the first job's end, not from 0 again
    assert [s for j, s in told if j == 2][-1] == second[-1]  # the viewer is sent where the second job ended
    shadows = ordered_rows(rec, "/images/rendered", "opt_step")
    # scrubbing past the second job's end shows its own last shadow (lit: it cast none), not the first job's
    assert shadows[-1]["t"] == second[5] and np.asarray(shadows[-1]["Image:buffer"]).min() == 255  # its own
