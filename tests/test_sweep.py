"""studio.imitate.sweep: the blocks, the draws, and a sweep on the real renderer and PyBullet that never worsens
a pose, keeps it collision-free and finds a finger moved anywhere in its range."""

from __future__ import annotations

import numpy as np
import pytest

from studio.imitate.config import LossConfig, SweepConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.rendered_loss import RenderedLoss
from studio.imitate.sweep import block_candidates, block_sweep, joint_blocks
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import finger_joint_indices
from studio.sim.shadow import Rig, ShadowRenderer


@pytest.fixture(scope="module")
def world(hand):
    with CollisionWorld(hand) as w:
        yield w


def test_blocks_are_the_wrist_then_each_finger_covering_every_joint_once(hand):
    blocks = joint_blocks(hand)
    fingers = finger_joint_indices(hand)
    assert len(blocks) == 1 + len(fingers) and blocks[0].tolist() == [hand.joint_names.index("wrist")]
    assert [b.tolist() for b in blocks[1:]] == list(fingers.values())
    assert sorted(np.concatenate(blocks).tolist()) == list(range(hand.dof))


def test_candidates_change_only_their_block_within_the_limits(hand, rng):
    theta = hand.rest_pose()
    block = joint_blocks(hand)[2]
    cfg = SweepConfig(local_share=0.25, local_sigma=0.1)
    cand = block_candidates(theta, block, 400, hand.lower, hand.upper, cfg, rng)
    others = np.setdiff1d(np.arange(hand.dof), block)
    assert cand.shape == (400, hand.dof)
    np.testing.assert_array_equal(cand[:, others], np.repeat(theta[None, others], 400, axis=0))
    assert np.all(cand >= hand.lower) and np.all(cand <= hand.upper)
    local = cand[300:, block]  # the last quarter is drawn near the current setting
    assert np.abs(local - theta[block]).max() < 0.1 * 6
    assert np.abs(cand[:300, block] - theta[block]).max() > 0.5  # the uniform draws roam the range


def _sweep_case(hand, world, seed):
    """A target rendered from a free pose and a start that differs from it in one finger's joints."""
    renderer = ShadowRenderer(hand, Rig(resolution=64))
    r = np.random.default_rng(seed)
    finger = joint_blocks(hand)[1 + seed % 5]
    while True:
        truth = np.clip(hand.rest_pose() + r.normal(0, 0.3, hand.dof), hand.lower, hand.upper)
        start = truth.copy()
        start[finger] = r.uniform(hand.lower[finger], hand.upper[finger])
        if not world.in_collision(np.stack([truth, start])).any():
            break
    loss = RenderedLoss(ImageLoss(renderer.render_one(truth), LossConfig(use_clip=False, crop_size=64)))
    return renderer, truth, start, lambda th: loss(renderer.render(th, check=False))[0]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sweep_never_worsens_stays_free_and_finds_the_moved_finger(hand, world, seed):
    renderer, truth, start, score = _sweep_case(hand, world, seed)
    start_loss = float(score(start[None])[0])
    seen, blocks_done = [], []
    cfg = SweepConfig(draws=512, wrist_draws=64, passes=3)
    theta, loss, scored = block_sweep(
        start, start_loss, joint_blocks(hand), hand.lower, hand.upper, score,
        lambda th: world.in_collision(th, check=False), cfg, np.random.default_rng(seed),
        on_better=lambda th, v: seen.append(v), progress=blocks_done.append,
    )  # fmt: skip
    assert loss == pytest.approx(float(score(theta[None])[0]), abs=1e-9)  # the loss it reports is the pose's
    assert loss <= start_loss and seen == sorted(seen, reverse=True) and (not seen or seen[-1] == loss)
    assert not world.in_collision(theta)[0]
    assert np.all(theta >= hand.lower) and np.all(theta <= hand.upper)
    assert scored >= 64 + 5 * 512
    assert [p.step for p in blocks_done] == list(range(1, len(blocks_done) + 1)) and 6 <= len(blocks_done) <= 3 * 6
    assert all(p.stage == "sweep" and p.total == 3 * 6 for p in blocks_done) and blocks_done[-1].best == loss
    assert start_loss > 0.02 and loss < 0.5 * start_loss  # the misplaced finger was found again


def test_cancel_stops_before_the_first_block(hand, world):
    import threading

    _, _, start, score = _sweep_case(hand, world, 0)
    stop = threading.Event()
    stop.set()
    theta, loss, scored = block_sweep(start, 1.0, joint_blocks(hand), hand.lower, hand.upper, score,
                                      lambda th: world.in_collision(th), SweepConfig(), np.random.default_rng(0),
                                      cancel=stop)  # fmt: skip
    assert scored == 0 and loss == 1.0
    np.testing.assert_array_equal(theta, start)


def test_config_is_checked():
    with pytest.raises(ValueError, match="starts ≥ 0"):
        SweepConfig(draws=0)
    with pytest.raises(ValueError, match="local_share"):
        SweepConfig(local_share=1.5)
    assert SweepConfig(starts=0).starts == 0  # off is allowed (the paper's method)
