"""The show preview's engine (studio.project.preview, studio.review.preview), checked on its pixels: the frames show
the source, the target in the studio's colours and the planned show's shadow as mounted, changing with the poses;
the side-by-side video plays them; the timeline's ticks wear their keyframe's status colour and late transitions are
shaded; a still's preview moves from home and holds the pose. The player and the strip: tests/test_show_player.py."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from preview_support import TILE, column, dark, give_results, horse, iou, plan, planned_horse, poses
from studio.assets import asset

from studio.project.preview import PreviewConfig, preview_inputs, render_preview
from studio.project.preview_clock import preview_clock
from studio.project.project import Project
from studio.project.sources import framed_frames
from studio.review.preview import decode_image
from studio.review.preview_strips import LATE_RGB, STATUS_RGB, timeline_image, timeline_x
from studio.review.sheets import BACKDROP, fit_tile, tint
from studio.sim.shadow import Rig, ShadowRenderer
from widgets.images import png


@pytest.fixture(scope="module")
def planned(tmp_path_factory, hand):
    """The horse planned and previewed (preview_support.planned_horse)."""
    return planned_horse(tmp_path_factory.mktemp("preview"), hand)


def test_preview_frames_show_source_target_and_the_shows_shadow_as_mounted(planned, hand):
    project, preview = planned
    s, show = project.state, project.show
    clock = preview.clock
    assert clock.planned and len(preview.frames) == len(clock.times) == round(show.duration * 25)
    frames = [decode_image(f) for f in preview.frames]
    assert all(f.shape == (TILE, 3 * TILE + 8, 3) for f in frames)
    sources = framed_frames(s.sources, s.frames, project.path, s.video)
    rolled = ShadowRenderer(hand, Rig(resolution=64, roll=project.mount.roll))
    upright = ShadowRenderer(hand, Rig(resolution=64))
    masks = project.combined_masks()
    for m in (0, len(frames) // 2, len(frames) - 1):
        rgb, i = frames[m], int(clock.frame[m])
        # the source column is the framed source frame (below the time written on it), not the mask
        src = column(rgb, "source")[40:].astype(float)
        assert np.abs(src - fit_tile(sources[i], TILE)[40:]).mean() < 8
        assert np.abs(src - tint(s.targets[i], masks[i], TILE)[40:]).mean() > 30
        # the target column: the shape dark (expressive parts tinted), the backdrop light, never the other way
        expected = tint(s.targets[i], masks[i], TILE)
        got = column(rgb, "target")
        assert np.median(np.abs(got.astype(float) - expected).max(axis=2)) < 10
        shape = tint(s.targets[i], None, TILE)[..., 0] == 40  # the shape's pixels at the tile's size
        plain = tint(np.zeros_like(s.targets[i]), masks[i], TILE)[..., 0] == BACKDROP[0]  # not expressive
        assert got[shape].mean() < 150 < got[~shape].mean()
        assert np.abs(got[~shape & plain].astype(float) - BACKDROP).mean() < 12
        # the shadow column is the show's pose at that time, rendered with the mount roll
        t = float(clock.times[m])
        seen = dark(column(rgb, "shadow"))
        want = dark(tint(rolled.render_one(show.sample(t)), None, TILE))
        assert iou(seen, want) > 0.9 > iou(seen, dark(tint(upright.render_one(show.sample(t)), None, TILE)))
    first, last = dark(column(frames[0], "shadow")), dark(column(frames[-1], "shadow"))
    assert (first != last).sum() > 0.02 * first.size  # the shadow moves with the show …
    assert iou(first, dark(column(frames[1], "shadow"))) > 0.8  # … smoothly


def test_the_side_by_side_video_plays_the_previews_frames(planned, tmp_path):
    """One way to say what plays when: side_by_side.mp4 shows, frame by frame, the preview clock's frame (late
    transitions stretched as planned) beside the show's shadow as mounted, at the source's rate."""
    import cv2

    from studio.project.outputs import write_outputs
    from studio.review.preview import preview_shadows
    from studio.review.video_review import side_by_side_frame

    project, _ = planned
    s = project.state
    path = write_outputs(project, tmp_path / "out")["side_by_side.mp4"]
    fps = next(src.fps for src in s.sources if src.kind != "still")
    clock = preview_clock(preview_inputs(project), fps)
    cap = cv2.VideoCapture(str(path))
    rate, frames = cap.get(cv2.CAP_PROP_FPS), []
    while (got := cap.read())[0]:
        frames.append(got[1][..., ::-1])
    cap.release()
    assert len(frames) == len(clock.times) > 2 and rate == pytest.approx(fps, rel=0.05)
    sources = framed_frames(s.sources, s.frames, project.path, s.video)
    shadows = preview_shadows(clock.theta, s.targets.shape[-1], project.mount.roll)
    masks = project.combined_masks()
    for m in (0, len(frames) // 2, len(frames) - 1):
        i = int(clock.frame[m])
        want = side_by_side_frame(sources[i], s.targets[i], masks[i], shadows[m], f"{clock.times[m]:.2f}s #{i}", TILE)
        assert frames[m].shape == want.shape and np.abs(frames[m].astype(float) - want).mean() < 10


def test_timeline_marks_keyframes_and_late_transitions(planned):
    project, preview = planned
    clock = preview.clock
    assert [t.keyframe for t in clock.ticks] == [kf.id for kf in project.keyframes]
    assert all(t.status == "current" for t in clock.ticks)
    assert clock.late, "the horse is faster than the servos: its show was stretched"
    img = timeline_image(clock, 640, 24)
    for tick in clock.ticks:
        x = int(timeline_x(tick.t, clock.start, clock.end, 640))
        assert tuple(img[3, x]) == STATUS_RGB["current"]
    a, b = clock.late[0]
    mid = int(timeline_x((a + b) / 2, clock.start, clock.end, 640))
    if all(abs(mid - int(timeline_x(t.t, clock.start, clock.end, 640))) > 2 for t in clock.ticks):
        assert tuple(img[3, mid]) == LATE_RGB
    # the late transitions shift the keyframes: each tick is at its marker on the show's clock
    marks = np.array([m.t for m in project.show.keyframes])
    assert all(np.isclose(marks, t.t).any() for t in clock.ticks)
    assert clock.ticks[-1].t > project.show_timing().keyframes.times[len(clock.ticks) - 1]


def test_timeline_tick_colours_follow_each_keyframes_status(tmp_path, hand):
    project = horse(tmp_path, roll=0.0)
    ids = [kf.id for kf in project.keyframes]
    give_results(project, hand, which=ids[:2])
    q = poses(hand, 3)[2]
    project.set_result(ids[2], q, {"total": 0.3}, np.zeros((64, 64), np.uint8), inputs="inputs-since-changed")
    status = project.status()
    assert status.result_state(ids[2]) == "stale" and status.result_state(ids[3]) == "missing"
    clock = preview_clock(preview_inputs(project), 25.0)
    assert not clock.planned and "no show" not in clock.note  # keyframes to optimise first
    img = timeline_image(clock, 640, 24)
    seen = {}
    for tick in clock.ticks:
        x = int(timeline_x(tick.t, clock.start, clock.end, 640))
        seen[tick.keyframe] = tuple(int(c) for c in img[2, x])
    assert seen == {k: STATUS_RGB[status.result_state(k)] for k in ids}
    # without a show each frame plays its keyframe's pose; a keyframe with none leaves the backdrop bare
    frames = render_preview(preview_inputs(project), PreviewConfig()).frames
    missing = [m for m, i in enumerate(clock.frame) if project.assignment()[i] >= 3]
    posed = [m for m, i in enumerate(clock.frame) if project.assignment()[i] < 2]
    assert not dark(column(decode_image(frames[missing[0]]), "shadow")).any()
    assert dark(column(decode_image(frames[posed[0]]), "shadow")).sum() > 200


def test_a_cancelled_preview_returns_nothing(planned):
    cancel = threading.Event()
    cancel.set()
    assert render_preview(preview_inputs(planned[0]), PreviewConfig(), cancel=cancel) is None


def test_a_stills_preview_moves_from_home_and_holds_the_pose(tmp_path, hand):
    project = Project.create(tmp_path / "still.shadow", sources=[asset("targets/asl_y.jpeg")], roll=0.0)
    give_results(project, hand)
    plan(project, hand)
    pose = project.results[project.keyframes[0].id].theta(hand.joint_names)
    preview = render_preview(preview_inputs(project), PreviewConfig(home=0.5))
    clock = preview.clock
    assert clock.times[0] < 0 <= clock.times[-1] and np.allclose(clock.theta[0], hand.rest_pose())
    assert np.allclose(clock.theta[-1], pose, atol=1e-6)
    frames = [decode_image(f) for f in preview.frames]
    renderer = ShadowRenderer(hand, Rig(resolution=project.state.targets.shape[-1]))
    rest = dark(tint(renderer.render_one(hand.rest_pose()), None, TILE))
    held = dark(tint(renderer.render_one(pose), None, TILE))
    assert iou(dark(column(frames[0], "shadow")), rest) > 0.9
    hold = [m for m, t in enumerate(clock.times) if t >= 0]
    assert len(hold) == 50  # the still's 2 s hold at 25 fps
    for m in hold[:: len(hold) // 5]:
        assert iou(dark(column(frames[m], "shadow")), held) > 0.9
    assert iou(rest, held) < 0.9
    assert np.array_equal(decode_image(png(timeline_image(clock))), timeline_image(clock))
