"""Keyframes refined together (studio.imitate.joint_refine): windows that cover the show, every result within the
pairs' distances and the boxes, never worse than the start, never in collision, and better than one keyframe after
another where the first one's own optimum holds the next back; cancel keeps the start; a sequence given the clock
refines its keyframes together (studio.imitate.together)."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest

from studio.imitate.config import JointConfig, LossConfig, RefineConfig, SearchConfig, SequenceConfig
from studio.imitate.joint_refine import TOL, objective, posed_box, refine_jointly, windows
from studio.imitate.sequence import SequenceImitator
from studio.imitate.together import Stretch, pose_backwards, refine_show, refine_together
from studio.motion.limits import JointLimits
from studio.motion.reach import clock_boxes, reach_pairs
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses
from studio.targets.expressive import expressive_masks

J = 21
LO, HI = np.full(J, -1.5), np.full(J, 1.5)


def quadratic(goal: np.ndarray):
    """A keyframe whose loss is its squared distance to ``goal (21,)``."""
    return lambda poses: ((np.asarray(poses) - goal) ** 2).sum(axis=-1)


def no_collision(poses: np.ndarray) -> np.ndarray:
    return np.zeros(len(poses), dtype=bool)


def greedy(goals: list[np.ndarray], d: float) -> np.ndarray:
    """One keyframe after another: each at its own goal, or as near as the one before it lets it be."""
    out = [goals[0]]
    for g in goals[1:]:
        out.append(np.clip(g, out[-1] - d, out[-1] + d))
    return np.stack(out)


def worst_excess(theta: np.ndarray, pairs: dict) -> float:
    return max(float((np.abs(theta[a] - theta[b]) - d).max()) for (a, b), d in pairs.items())


@pytest.mark.parametrize(
    ("k", "width", "expected"),
    [(2, 3, [[0, 1]]), (3, 3, [[0, 1, 2]]), (4, 3, [[0, 1, 2], [1, 2, 3]]), (5, 3, [[0, 1, 2], [2, 3, 4]]),
     (6, 2, [[0, 1], [1, 2], [2, 3], [3, 4], [4, 5]])],
)  # fmt: skip
def test_windows_cover_the_show_each_overlapping_the_last(k, width, expected):
    got = windows(k, width)
    assert got == expected
    assert sorted({i for w in got for i in w}) == list(range(k))


def test_together_beats_one_after_another_within_the_reach():
    rng = np.random.default_rng(0)
    goals = [rng.uniform(-0.6, 0.6, J) for _ in range(3)]
    d = 0.1
    pairs = {(0, 1): np.full(J, d), (1, 2): np.full(J, d), (0, 2): np.full(J, 2 * d)}
    start = greedy(goals, d)
    cfg = JointConfig(generations=150, popsize=24, sigma0=0.1)
    got = refine_jointly([quadratic(g) for g in goals], start, pairs, [(LO, HI)] * 3, no_collision, cfg)
    assert got.start_loss == pytest.approx(sum(((s - g) ** 2).sum() for s, g in zip(start, goals, strict=True)))
    assert got.loss < 0.8 * got.start_loss  # the first keyframe gives a little for the others to reach theirs
    assert worst_excess(got.theta, pairs) <= TOL
    assert (got.theta >= LO).all() and (got.theta <= HI).all() and not got.cancelled


def test_held_boxes_and_collisions_are_never_left():
    rng = np.random.default_rng(1)
    goals = [rng.uniform(-0.6, 0.6, J) for _ in range(2)]
    d = 0.1
    pairs = {(0, 1): np.full(J, d)}
    start = greedy(goals, d)
    box0 = (start[0] - 0.05, start[0] + 0.05)  # keyframe 0 held near its start by a pose outside the show

    def collides(poses):  # a forbidden half-space on joint 3 that the goal of keyframe 1 lies in
        return np.asarray(poses)[:, 3] > start[1, 3] + 0.02

    got = refine_jointly([quadratic(g) for g in goals], start, pairs, [box0, (LO, HI)], collides,
                         JointConfig(generations=120, popsize=16))  # fmt: skip
    assert got.loss <= got.start_loss
    assert (got.theta[0] >= box0[0] - 1e-12).all() and (got.theta[0] <= box0[1] + 1e-12).all()
    assert not collides(got.theta[1:2])[0]
    assert worst_excess(got.theta, pairs) <= TOL


def test_a_start_at_the_optimum_is_kept_and_the_temporal_term_counts():
    goal = np.linspace(-0.3, 0.3, J)
    start = np.stack([goal, goal])
    pairs = {(0, 1): np.full(J, 0.1)}
    got = refine_jointly([quadratic(goal)] * 2, start, pairs, [(LO, HI)] * 2, no_collision,
                         JointConfig(generations=30, popsize=8), previous=goal + 0.2, w_temporal=0.2)  # fmt: skip
    assert got.loss <= got.start_loss
    want = objective(start[None], np.zeros((1, 2)), goal + 0.2, 0.2)[0]  # only the term against `previous`
    assert got.start_loss == pytest.approx(want)


def test_the_start_with_the_lowest_sum_is_refined():
    """Of the poses given and the alternatives (the keyframes posed in the other order), refinement starts from the
    one whose objective is lowest, and says which."""
    rng = np.random.default_rng(2)
    goals = [rng.uniform(-0.6, 0.6, J) for _ in range(3)]
    pairs = {(0, 1): np.full(J, 0.1), (1, 2): np.full(J, 0.1), (0, 2): np.full(J, 0.2)}
    forward = greedy(goals, 0.1)
    backward = greedy(goals[::-1], 0.1)[::-1]  # the last keyframe at its goal, each earlier one as near as it can
    scorers = [quadratic(g) for g in goals]
    sums = [objective(t[None], np.array([[s(t[i : i + 1])[0] for i, s in enumerate(scorers)]]), None, 0.0)[0]
            for t in (forward, backward)]  # fmt: skip
    off = JointConfig(generations=0)
    for order in ((forward, backward), (backward, forward)):
        got = refine_jointly(scorers, order[0], pairs, [(LO, HI)] * 3, no_collision, off, alternatives=[order[1]])
        best = int(np.argmin(sums))
        assert got.start_loss == pytest.approx(min(sums)) and got.loss == got.start_loss
        np.testing.assert_array_equal(got.theta, (forward, backward)[best])
        assert got.chosen == (best if order[0] is forward else 1 - best)
    got = refine_jointly(scorers, forward, pairs, [(LO, HI)] * 3, no_collision, JointConfig(generations=40),
                         alternatives=[backward])  # fmt: skip
    assert got.loss <= min(sums) and worst_excess(got.theta, pairs) <= TOL
    with pytest.raises(ValueError, match="every start"):
        refine_jointly(scorers, forward, pairs, [(LO, HI)] * 3, no_collision, off, alternatives=[forward[:2]])


def test_cancel_keeps_the_start():
    goals = [np.zeros(J), np.full(J, 0.5)]
    start = greedy(goals, 0.1)
    cancel = threading.Event()
    cancel.set()
    got = refine_jointly([quadratic(g) for g in goals], start, {(0, 1): np.full(J, 0.1)}, [(LO, HI)] * 2,
                         no_collision, JointConfig(generations=50), cancel=cancel)  # fmt: skip
    assert got.cancelled and np.array_equal(got.theta, start) and got.loss == got.start_loss


def test_progress_counts_every_generation_of_every_window():
    goals = [np.full(J, x) for x in (0.0, 0.3, 0.6, 0.9)]
    pairs = {(i, i + 1): np.full(J, 0.1) for i in range(3)}
    seen = []
    refine_jointly([quadratic(g) for g in goals], greedy(goals, 0.1), pairs, [(LO, HI)] * 4, no_collision,
                   JointConfig(generations=5, popsize=4, window=3), progress=seen.append)  # fmt: skip
    assert [p.step for p in seen] == list(range(1, 11)) and {p.total for p in seen} == {10}
    assert all(p.stage == "together" for p in seen)
    assert [p.best for p in seen] == sorted((p.best for p in seen[:5]), reverse=True) + sorted(
        (p.best for p in seen[5:]), reverse=True
    )  # each window's best only falls


TINY = SequenceConfig(first=SearchConfig(batch=8, iterations=10), next=SearchConfig(batch=8, iterations=8),
                      refine=RefineConfig(steps=20, restarts=1), candidates=1, retrieve=False)  # fmt: skip


def free_pose(hand, seed: int) -> np.ndarray:
    """A random pose ``(21,)`` rad of the hand that does not penetrate itself."""
    rng = np.random.default_rng(seed)
    with CollisionWorld(hand) as world:
        q = sample_poses(hand, 1, rng)[0][0]
        while world.in_collision(q)[0]:
            q = sample_poses(hand, 1, rng)[0][0]
    return q


def three_steps(hand, q: np.ndarray, joints: list[int], size: float) -> np.ndarray:
    """``(3, 21)`` rad: ``q`` and two steps of ``size`` rad on ``joints`` from it, within the limits."""
    step = np.zeros(J)
    step[joints] = size
    return np.clip(q + np.arange(3)[:, None] * step, hand.lower, hand.upper)


def test_a_sequence_given_the_clock_refines_its_keyframes_together(hand):
    """SequenceImitator.imitate with the clock's pairs (Table 2's studio row): the keyframes posed one after another,
    then together; within every pair's reach, each result scored again, and the sum it optimises never higher."""
    tiny = TINY  # a tiny budget: the structure is tested, not the method
    with SequenceImitator(cfg=tiny, loss_cfg=LossConfig(use_clip=False, crop_size=128)) as seq:
        masks = seq.renderer.render(three_steps(hand, free_pose(hand, 3), [1, 2, 5, 6, 9, 10], 0.3))
        exp = expressive_masks(masks)
        times = {(0, 1): 0.25, (1, 2): 0.25}
        limits = JointLimits.from_hand(hand)
        boxes, pairs = clock_boxes(times, limits), reach_pairs(times, limits)
        alone = seq.imitate(masks, exp, box_for=boxes)  # one after another only
        joint = seq.imitate(masks, exp, box_for=boxes, pairs=pairs,
                            cfg=replace(tiny, joint=JointConfig(generations=40, popsize=12)))  # fmt: skip
    assert all("together" not in k.timings for k in alone.keyframes)
    assert all("together" in k.timings for k in joint.keyframes) and not joint.cancelled
    got = joint.thetas
    assert worst_excess(got, pairs) <= TOL and all(k.collision_free for k in joint.keyframes)
    assert sum(k.loss["total"] for k in joint.keyframes) <= sum(k.loss["total"] for k in alone.keyframes) + 1e-9
    for k in joint.keyframes:  # scored again at its new pose: the shadow is that pose's
        np.testing.assert_array_equal(k.shadow, seq.renderer.render_one(k.theta))


def test_keyframes_posed_last_to_first_keep_the_reach_and_the_lower_sum_is_refined(hand):
    """With ``both_orders`` the keyframes are posed again last to first, each within reach of those after it and
    inside its own box; the refinement starts from the order whose sum is lower; a cancel while posing them keeps
    the poses given."""
    tiny = TINY  # a tiny budget: the structure is tested, not the method
    both = replace(tiny, joint=JointConfig(generations=20, popsize=8, both_orders=True))
    q = free_pose(hand, 5)
    with SequenceImitator(cfg=tiny, loss_cfg=LossConfig(use_clip=False, crop_size=128)) as seq:
        poses = three_steps(hand, q, [0, 3, 4, 7, 8, 11], 0.35)
        masks = seq.renderer.render(poses)
        exp = expressive_masks(masks)
        limits = JointLimits.from_hand(hand)
        pairs = reach_pairs({(0, 1): 0.25, (1, 2): 0.25}, limits)
        held = 2 * poses[0] - poses[1]  # 0.25 s before keyframe 0 (keyframe k: 1 + k of this clock)
        clock = clock_boxes({(0, 1): 0.25, (1, 2): 0.25, (2, 3): 0.25}, limits)
        forward = seq.imitate(masks, exp, box_for=lambda k, done: clock(k + 1, [held, *done])).thetas

        def box_of(k):  # each keyframe's box from the held pose
            return clock(k + 1, [held])

        stretch = Stretch(masks, exp, pairs, box_of)
        seen = []
        back = pose_backwards(seq, stretch, tiny, progress=seen.append)
        assert back.shape == (3, J) and worst_excess(back, pairs) <= 1e-9
        for k in range(3):
            assert (back[k] >= box_of(k)[0] - 1e-9).all() and (back[k] <= box_of(k)[1] + 1e-9).all()
        assert seen and all(p.stage.startswith("last to first: keyframe ") for p in seen)
        named = [p.stage.split(":")[1].strip() for p in seen]  # the show's keyframes, the last one first
        assert list(dict.fromkeys(named)) == ["keyframe 3/3", "keyframe 2/3", "keyframe 1/3"]
        seen.clear()
        again = pose_backwards(seq, replace(stretch, ids=[7, 8, 9]), tiny, progress=seen.append)
        np.testing.assert_array_equal(again, back)  # the same poses, named by a project's ids
        named = [p.stage.split(":")[1].strip() for p in seen]
        assert list(dict.fromkeys(named)) == ["keyframe 9 (3 of 3)", "keyframe 8 (2 of 3)", "keyframe 7 (1 of 3)"]
        assert list(dict.fromkeys(p.item for p in seen)) == ["9", "8", "7"]  # each report names its keyframe

        def start_sum(theta):  # the sum a refinement of no generations keeps: its start's
            off = replace(tiny, joint=JointConfig(generations=0))
            return refine_together(seq.imitator, stretch, theta, off)[1].start_loss

        scored, got = refine_show(seq, stretch, forward, both)
        assert got.start_loss <= start_sum(forward) + 1e-9 and got.loss <= got.start_loss
        assert got.start_loss == pytest.approx(start_sum(forward) if got.chosen == 0 else start_sum(back))
        assert worst_excess(got.theta, pairs) <= TOL and all(s.collision_free for s in scored)
        orders_only = replace(tiny, joint=JointConfig(generations=0, both_orders=True))  # no refinement: the order
        assert orders_only.joint.enabled and not JointConfig().enabled
        got = seq.imitate(masks, exp, box_for=lambda k, done: clock(k + 1, [held, *done]), pairs=pairs,
                          cfg=orders_only)  # fmt: skip
        assert all("together" in k.timings for k in got.keyframes) and worst_excess(got.thetas, pairs) <= TOL
        cancel = threading.Event()
        cancel.set()
        _, stopped = refine_show(seq, stretch, forward, both, cancel=cancel)
        assert stopped.cancelled and stopped.chosen == 0 and np.array_equal(stopped.theta, forward)


def test_a_posed_box_keeps_every_posed_pairs_distance_and_pins_crossed_joints_to_the_middle():
    d = np.full(J, 0.1)
    pairs = {(0, 1): d, (1, 2): d, (0, 2): 2 * d}
    posed = {2: np.full(J, 0.5)}

    def box(k, poses, lower=LO, upper=HI):
        return np.stack(posed_box(k, poses, pairs, lower, upper))

    np.testing.assert_allclose(box(1, posed), [np.full(J, 0.4), np.full(J, 0.6)])
    own = np.full(J, 0.45)  # keyframe 0's own box ends below keyframe 2's reach
    np.testing.assert_allclose(box(0, posed, upper=own), [np.full(J, 0.3), own])
    far = {0: np.full(J, -0.5), 2: np.full(J, 0.5)}  # keyframe 1 cannot reach both: pinned between them
    np.testing.assert_allclose(box(1, far), np.zeros((2, J)), atol=1e-12)
    np.testing.assert_array_equal(box(1, {}), [LO, HI])  # nothing posed: its own box
