"""Shows that keep the clock: the servos' reach in a transition's time (checked against Ruckig itself), the box a
keyframe keeps, and a planned sequence whose every transition meets the servo limits at the video's clock."""

from __future__ import annotations

import numpy as np
import pytest
from ruckig import InputParameter, Ruckig, Trajectory

from studio.motion.limits import JointLimits
from studio.motion.reach import clock_boxes, reach, reach_box, reach_distances, rest_to_rest_time


@pytest.fixture(scope="module")
def limits(hand):
    return JointLimits.from_hand(hand)


def ruckig_time(d: float, v: float, a: float, j: float) -> float:
    """The reference: Ruckig's time-optimal rest-to-rest duration for one joint."""
    otg, inp, traj = Ruckig(1), InputParameter(1), Trajectory(1)
    inp.current_position, inp.target_position = [0.0], [float(d)]
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [v], [a], [j]
    otg.calculate(inp, traj)
    return traj.duration


def test_rest_to_rest_time_is_ruckigs(limits, rng):
    """Every regime (pure jerk, an acceleration plateau, a cruise) against Ruckig, per joint."""
    for d in [1e-4, 0.01, 0.1, 0.3, 0.45, 0.8, 1.2, 2.0, 3.0, *rng.uniform(0, 3, 12)]:
        ours = rest_to_rest_time(np.full(len(limits.velocity), d), limits)
        for j in (0, 1, 7):  # the wrist (half the limits) and two fingers
            ref = ruckig_time(d, limits.velocity[j], limits.acceleration[j], limits.jerk[j])
            assert ours[j] == pytest.approx(ref, rel=1e-6, abs=1e-9), (d, j)
    other = JointLimits(limits.lower, limits.upper, np.full(21, 1.0), np.full(21, 50.0), np.full(21, 100.0))
    for d in (0.05, 0.5, 2.5):  # v < a²/j: the speed is reached without an acceleration plateau
        assert rest_to_rest_time(np.full(21, d), other)[0] == pytest.approx(ruckig_time(d, 1.0, 50.0, 100.0))


def test_reach_inverts_the_time(limits):
    for dt in (0.05, 0.125, 0.25, 0.5, 1.0, 2.0):
        r = reach(dt, limits)
        assert (r > 0).all() and np.allclose(rest_to_rest_time(r, limits), dt, atol=1e-6)
        assert (rest_to_rest_time(r + 1e-3, limits) > dt).all()
    assert reach(0.25, limits)[0] < reach(0.25, limits)[1]  # the wrist, at half the limits, reaches less
    assert not reach(0.0, limits).any()


def test_a_box_keeps_the_reach_of_every_neighbour(limits, hand):
    a, b = hand.rest_pose(), hand.rest_pose().copy()
    b[7] += 0.5
    lo, hi = reach_box([(a, 0.5), (b, 0.5)], limits, margin=1.0)
    r = reach(0.5, limits)
    assert (lo >= limits.lower).all() and (hi <= limits.upper).all() and (lo <= hi).all()
    assert hi[7] == pytest.approx(min(a[7] + r[7], limits.upper[7])) and lo[7] == pytest.approx(b[7] - r[7])
    far = hand.rest_pose().copy()
    far[7] = a[7] + 3 * r[7]  # further apart than two reaches: pinned between them
    lo, hi = reach_box([(a, 0.5), (far, 0.5)], limits, margin=1.0)
    assert lo[7] == hi[7] == pytest.approx((a[7] + far[7]) / 2)


def test_a_box_from_the_whole_clock_leaves_room_for_the_keyframes_after_it(limits, hand):
    """A → B (0.3 s) → C (0.2 s) → A (0.2 s), posed in order, B as far from A as its box lets it: C still has a pose
    within reach of both (with B boxed by its direct neighbour A alone, B took the reach C needs and C's box
    crossed), and the distance that bounds B is the shortest chain of moves: min(reach(0.3), 2 reach(0.2))."""
    times = {(0, 1): 0.3, (1, 2): 0.2, (2, 0): 0.2}
    far = reach_distances(times, limits, margin=1.0)
    assert far[0][1] == pytest.approx(np.minimum(reach(0.3, limits), 2 * reach(0.2, limits)))
    box_for = clock_boxes(times, limits, margin=1.0)
    a = hand.rest_pose()
    b = box_for(1, [a])[1]  # as far as it may go
    lo, hi = box_for(2, [a, b])
    c = (lo + hi) / 2
    for x, y, dt in ((a, b, 0.3), (b, c, 0.2), (c, a, 0.2)):
        assert rest_to_rest_time(x - y, limits).max() <= dt * (1 + 1e-6)


@pytest.mark.slow
def test_every_transition_of_a_planned_sequence_meets_the_servo_limits_at_the_videos_clock(hand, limits):
    """Two far-apart shapes at 4 Hz (A A A B B B A A): free, the poses need more than the 0.25 s each move has;
    kept to the clock, the show plans without a late transition and as long as the sampled video."""
    from studio.imitate.config import CPU_SEQUENCE, RefineConfig, SearchConfig
    from studio.imitate.sequence import SequenceImitator
    from studio.motion.errors import SegmentTooFastError
    from studio.motion.plan import plan_show
    from studio.motion.video_timing import video_end, video_keyframes
    from studio.sim.shadow import Rig, ShadowRenderer

    renderer = ShadowRenderer(hand, Rig(resolution=128))
    pose_a, pose_b = hand.rest_pose(), hand.rest_pose().copy()
    pose_b[[0, 6, 7, 10, 11]] = [1.2, -0.6, 1.2, -0.6, 1.2]  # the wrist turned, two fingers bent
    masks = renderer.render(np.stack([pose_a, pose_b]))
    times, assignment = np.arange(8) * 0.25, np.array([0, 0, 0, 1, 1, 1, 0, 0])
    end = video_end(times, 4.0)
    seq_cfg = CPU_SEQUENCE.__class__(
        first=SearchConfig(batch=8, iterations=10, lr=0.08), next=SearchConfig(batch=4, iterations=10, lr=0.08),
        refine=RefineConfig(**{**CPU_SEQUENCE.refine.__dict__, "steps": 10}), candidates=1, expressive=False,
        retrieve=False,
    )  # fmt: skip
    dt = 0.25  # both moves (A → B and B → A) have one sample period

    def box_for(k, done):
        return reach_box([(th, dt) for th in done], limits, seq_cfg.clock_margin) if done else None

    with SequenceImitator(None, seq_cfg) as seq:
        kept = seq.imitate(masks, box_for=box_for)
        free = seq.imitate(masks)
    step = np.abs(kept.thetas[1] - kept.thetas[0])
    assert (step <= reach(seq_cfg.clock_margin * dt, limits) + 1e-6).all()
    assert kept.keyframes[1].collision_free
    timing = video_keyframes(times, assignment, kept.thetas, end)
    show = plan_show(hand, timing.keyframes).show  # no allow_late: a late transition would raise
    assert show.duration == pytest.approx(end) and not show.provenance["late_segments"]
    if (np.abs(free.thetas[1] - free.thetas[0]) > reach(dt, limits)).any():  # unconstrained poses: too fast
        with pytest.raises(SegmentTooFastError):
            plan_show(hand, video_keyframes(times, assignment, free.thetas, end).keyframes)
