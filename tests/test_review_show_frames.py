"""A project's recording shows, on ``show_time``, the frame the show player plays (studio.review.show_frames): a
viewer that follows the player shows that frame's target, expressive mask and keyframe shadows, not empty views;
logged again after the show is planned otherwise, no row of the earlier plan shows a frame the new one does not play
then."""

from __future__ import annotations

import numpy as np
import pytest
from preview_support import give_results, horse, plan

from studio.project.preview import preview_inputs
from studio.project.preview_clock import preview_clock
from studio.review.frames import KeyframeReview
from studio.review.readback import ordered_rows, read_recording
from studio.review.recording import ProjectRecording
from studio.review.rig3d import RigReview
from studio.review.sheets import display
from studio.review.show_frames import log_show_frames
from studio.sim.shadow import Rig

pytestmark = pytest.mark.slow


def images_on(recording: dict, entity: str, timeline: str = "show_time") -> list[tuple[float, np.ndarray | None]]:
    """``(time s, image bytes or None for a Clear)`` of every row of ``entity`` on ``timeline``, in the order Rerun
    resolves them (rows at one time in the order logged: the last one is what a viewer shows)."""
    rows = ordered_rows(recording, entity, timeline)
    return [(r["t"] / 1e9, None if r.get("Image:buffer") is None else np.asarray(r["Image:buffer"][0], np.uint8))
            for r in rows]  # fmt: skip


def shown_at(rows: list[tuple[float, np.ndarray | None]], t: float) -> np.ndarray | None:
    """What a viewer shows at ``t``: the last row at or before it."""
    before = [image for time, image in rows if time <= t + 1e-9]
    return before[-1] if before else None


def test_a_viewer_on_show_time_shows_the_frame_the_player_plays(tmp_path, hand):
    project = horse(tmp_path)  # the horse: 5 frames, 5 keyframes, its show faster than the servos (stretched)
    give_results(project, hand)
    plan(project, hand)
    show_times = project.frame_show_times()
    assert show_times is not None and np.all(np.diff(show_times) > 0)
    clock = preview_clock(preview_inputs(project), fps=25.0)  # what the show player plays, when
    assert not np.allclose(show_times, [f.time_s for f in project.frames])  # the stretch moved the frames
    with ProjectRecording(tmp_path / "r.rrd", rig=Rig(resolution=64), cfg=RigReview(texture=32)) as review:
        review.log_project(project)
        review.log_project(project)  # logged again (after any edit): nothing else appears
    rec = read_recording(tmp_path / "r.rrd")
    targets = np.asarray(project.state.targets)
    rows = images_on(rec, "/images/target")
    assert sorted({t for t, _ in rows}) == pytest.approx(show_times.tolist(), abs=1e-6)
    rendered = images_on(rec, "/images/rendered")
    which = project.assignment()
    for t, k in zip(clock.times, clock.frame):
        if t < 0:  # the move from home, before the first frame plays
            continue
        assert np.array_equal(shown_at(rows, t), display(targets[k]).ravel()), (t, k)
        result = project.results[project.keyframes[int(which[k])].id]
        assert np.array_equal(shown_at(rendered, t), display(result.shadow).ravel()), (t, k)


def test_rows_of_an_earlier_plan_show_the_frame_played_now(tmp_path):
    targets = np.zeros((3, 8, 8), np.uint8)
    for k in range(3):
        targets[k, k : k + 3, 2:5] = 1  # three frames told apart by their pixels
    keyframes = [KeyframeReview(0, 0, (0, 1, 2), shadow=targets[0])]
    path = tmp_path / "r.rrd"
    with ProjectRecording(path, rig=Rig(resolution=16), cfg=RigReview(texture=8)) as review:
        logged = log_show_frames(review.rec, targets, targets, keyframes, np.zeros(3, int), np.array([0.0, 1.0, 2.0]))
        log_show_frames(review.rec, targets, targets, keyframes, np.zeros(3, int), np.array([0.0, 1.5, 3.0]),
                        logged=logged)  # fmt: skip
    assert logged.times.tolist() == [0.0, 1.0, 1.5, 2.0, 3.0]
    rows = images_on(read_recording(path), "/images/target")
    for t, k in ((0.5, 0), (1.2, 0), (1.7, 1), (2.5, 1), (3.2, 2)):  # the second plan: frame 1 from 1.5 s, 2 from 3
        assert np.array_equal(shown_at(rows, t), display(targets[k]).ravel()), (t, k)
    assert shown_at(images_on(read_recording(path), "/images/source"), 1.0) is None  # no source: cleared
