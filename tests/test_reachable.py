"""studio.evaluate.reachable: targets the hand can cast (collision-free known poses, framed like image files) and
the summary against their floor."""

from __future__ import annotations

import numpy as np
import pytest

from studio.evaluate.reachable import ReachableConfig, reach_summary, reachable_targets
from studio.imitate.config import LossConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.rendered_loss import RenderedLoss
from studio.sim.physics import CollisionWorld
from studio.sim.shadow import Rig, ShadowRenderer
from studio.targets.images import TargetConfig, shadow_box


@pytest.fixture(scope="module")
def drawn(hand):
    with CollisionWorld(hand) as world:
        cfg = ReachableConfig(count=5, seed=3, fine=256)
        theta, targets = reachable_targets(hand, world, 64, cfg)
        assert not world.in_collision(theta).any()
    return theta, targets


def test_targets_are_framed_binary_shadows_of_free_poses(hand, drawn):
    theta, targets = drawn
    assert theta.shape == (5, hand.dof) and targets.shape == (5, 64, 64) and targets.dtype == np.uint8
    assert np.all(theta >= hand.lower) and np.all(theta <= hand.upper)
    assert set(np.unique(targets)) <= {0, 1}
    for t in targets:  # framed like a loaded image: the longer side of the box spans 1 / (1 + 2·margin) of it
        r0, r1, c0, c1 = shadow_box(t)
        assert max(r1 - r0, c1 - c0) == pytest.approx(64 / (1 + 2 * TargetConfig().margin), abs=2)


def test_the_known_pose_scores_near_zero_and_a_different_one_does_not(hand, drawn):
    theta, targets = drawn
    renderer = ShadowRenderer(hand, Rig(resolution=64))
    for i, t in enumerate(targets):
        loss = RenderedLoss(ImageLoss(t, LossConfig(use_clip=False, crop_size=64)))
        own = loss(renderer.render(theta[i : i + 1]))[1]["iou_loss"][0]
        other = loss(renderer.render(theta[(i + 1) % 5 : (i + 1) % 5 + 1]))[1]["iou_loss"][0]
        assert own < 0.2 and other > own


def test_draws_are_seeded(hand, drawn):
    with CollisionWorld(hand) as world:
        again, _ = reachable_targets(hand, world, 64, ReachableConfig(count=5, seed=3, fine=256))
        other, _ = reachable_targets(hand, world, 64, ReachableConfig(count=5, seed=4, fine=256))
    np.testing.assert_array_equal(again, drawn[0])
    assert not np.allclose(other, drawn[0])


def test_summary_against_the_floor():
    s = reach_summary(np.array([0.10, 0.30, 0.05]), np.array([0.09, 0.10, 0.07]))
    assert s["iou_loss"] == pytest.approx(0.15) and s["floor"] == pytest.approx(0.26 / 3)
    assert s["excess"] == pytest.approx((0.01 + 0.20 + 0.0) / 3)  # below the floor counts as reached, not negative
    assert s["reached_pct"] == pytest.approx(200 / 3)
    with pytest.raises(ValueError, match="count"):
        ReachableConfig(count=0)
