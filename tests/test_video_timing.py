"""Show timing of a video: frames + assignment + keyframe poses → planner keyframes on the video's clock."""

from __future__ import annotations

import numpy as np
import pytest

from studio.motion.errors import PlanError, SegmentTiming
from studio.motion.plan import PlanConfig, plan_show
from studio.motion.timing import TimingConfig
from studio.motion.video_timing import runs_of, video_end, video_keyframes
from studio.sim.hand import load_hand


@pytest.fixture(scope="module")
def hand():
    return load_hand()


def poses(hand, k: int, step: float = 0.05) -> np.ndarray:
    """``k`` distinct collision-free poses close to rest (small steps of every finger's flexion)."""
    rest = hand.rest_pose()
    flex = [i for i, n in enumerate(hand.joint_names) if n.endswith("mcp_flex")]
    out = np.repeat(rest[None], k, axis=0)
    for c in range(k):
        out[c, flex] += step * c
    return np.clip(out, hand.lower, hand.upper)


def test_runs_of():
    assert runs_of(np.array([0, 0, 1, 1, 0])) == [(0, 1), (2, 3), (4, 4)]
    assert runs_of(np.array([3])) == [(0, 0)]
    assert runs_of(np.array([0, 1, 0, 1])) == [(0, 0), (1, 1), (2, 2), (3, 3)]


def test_aabba_keyframes_at_the_run_times_with_holds(hand):
    times = np.array([0.0, 0.25, 0.5, 0.75, 1.0])
    q = poses(hand, 2)
    vt = video_keyframes(times, np.array([0, 0, 1, 1, 0]), q, end_s=1.25, source_frames=np.arange(5) * 6)
    kf = vt.keyframes
    # A reached at 0, held to its last frame (0.25); B reached at 0.5, held to 0.75; A again at 1.0, held to the end
    assert kf.times.tolist() == [0.0, 0.25, 0.5, 0.75, 1.0, 1.25]
    assert vt.cluster.tolist() == [0, 0, 1, 1, 0, 0]
    assert vt.frame.tolist() == [0, 1, 2, 3, 4, 4]
    assert kf.hold.tolist() == [True] * 6
    assert kf.source_frame == [0, 6, 12, 18, 24, 24]
    np.testing.assert_array_equal(kf.poses, q[[0, 0, 1, 1, 0, 0]])
    assert vt.runs == [(0, 1), (2, 3), (4, 4)]


def test_single_frame_runs_pass_a_loop_stays_a_loop(hand):
    times = np.arange(6) * 0.5
    q = poses(hand, 2)
    vt = video_keyframes(times, np.array([0, 1, 0, 1, 0, 1]), q, end_s=3.0)
    assert vt.keyframes.times.tolist() == [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0]
    assert vt.cluster.tolist() == [0, 1, 0, 1, 0, 1, 1]  # A→B→A→B…, never merged into one A and one B
    assert vt.keyframes.hold.tolist() == [False] * 5 + [True, True]  # shown, not held; the last run holds to the end


def test_plans_to_a_show_on_the_video_clock_as_long_as_the_video(hand):
    times = np.array([0.0, 0.5, 1.0, 1.5, 2.0, 2.5])
    end = video_end(times, hz=2.0)
    assert end == pytest.approx(3.0)
    assignment = np.array([0, 0, 1, 1, 0, 0])
    q = poses(hand, 2)
    vt = video_keyframes(times, assignment, q, end_s=end)
    assert vt.keyframes.times.tolist() == [0.0, 0.5, 1.0, 1.5, 2.0, 3.0]  # the last run holds to the end
    result = plan_show(hand, vt.keyframes)
    show = result.show
    assert not result.home_added  # the first frame at t = 0 is the show's start
    assert show.duration == pytest.approx(end)
    # every frame plays its cluster's pose at its time: the show passes each keyframe exactly
    np.testing.assert_allclose(show.sample(times), q[assignment], atol=1e-9)
    np.testing.assert_allclose(show.sample([0.25, 1.25, 2.75]), q[[0, 1, 0]], atol=1e-9)  # held between frames


def test_first_frame_after_zero_is_reached_from_home(hand):
    times = np.array([0.5, 1.0])
    vt = video_keyframes(times, np.array([0, 1]), poses(hand, 2), end_s=video_end(times, hz=2.0))
    result = plan_show(hand, vt.keyframes)
    assert result.home_added
    np.testing.assert_allclose(result.show.sample(0.0), hand.rest_pose(), atol=1e-9)
    assert result.show.duration == pytest.approx(1.5)


def test_video_end_stops_at_the_source_end():
    times = np.array([0.0, 0.3, 0.5, 0.8, 1.0])
    assert video_end(times, hz=4.0) == pytest.approx(1.25)
    assert video_end(times, hz=4.0, duration_s=1.1) == pytest.approx(1.1)
    assert video_end(times, hz=4.0, duration_s=0.9) == pytest.approx(1.25)  # an end before the last frame: ignored


def test_too_fast_transitions_are_named_by_frame(hand):
    times = np.array([0.0, 0.1, 0.2])
    far = poses(hand, 2, step=1.0)
    vt = video_keyframes(times, np.array([0, 1, 1]), far, end_s=0.3)
    result = plan_show(hand, vt.keyframes, PlanConfig(timing=TimingConfig(allow_late=True)))
    late = vt.late_transitions(result.trajectory.late, result.home_added)
    assert late and late[0]["from_frame"] == 0 and late[0]["to_frame"] == 1
    assert late[0]["given_s"] == pytest.approx(0.1) and late[0]["needed_s"] > 0.1
    assert result.show.duration > 0.3  # stretched: later keyframes shift
    home = vt.late_transitions([SegmentTiming(0, 0.0, 0.1, 0.4)], home_added=True)
    assert home[0]["from_frame"] is None and home[0]["to_frame"] == 0


def test_bad_input_is_a_plan_error(hand):
    q = poses(hand, 2)
    with pytest.raises(PlanError, match="increasing"):
        video_keyframes(np.array([0.0, 0.0]), np.array([0, 1]), q, end_s=1.0)
    with pytest.raises(PlanError, match="poses"):
        video_keyframes(np.array([0.0, 0.5]), np.array([0, 2]), q, end_s=1.0)
    with pytest.raises(PlanError, match="end"):
        video_keyframes(np.array([0.0, 0.5]), np.array([0, 1]), q, end_s=0.5)
