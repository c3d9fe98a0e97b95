"""Self-collision score and check: known poses, and the fast path against the all-pairs reference."""

from __future__ import annotations

import numpy as np
import pytest

from studio.sim.physics import CollisionConfig, CollisionWorld
from studio.sim.sampling import sample_poses


@pytest.fixture(scope="module")
def world(hand):
    with CollisionWorld(hand) as w:
        yield w


def crossed_fingers(hand) -> np.ndarray:
    """Middle finger swung fully towards the index while the index stays straight: they pass through each other."""
    q = hand.rest_pose()
    q[hand.joint_names.index("middle_mcp_abd")] = np.radians(-15)
    return q


def test_rest_pose_scores_zero(world, hand):
    assert world.collision_score(hand.rest_pose())[0] == 0.0
    assert not world.in_collision(hand.rest_pose())[0]
    assert world.contacts(hand.rest_pose()) == []


def test_crossed_fingers_collide(world, hand):
    q = crossed_fingers(hand)
    assert world.collision_score(q)[0] > 0
    assert world.in_collision(q)[0]
    names = {(c.link_a, c.link_b) for c in world.contacts(q)}
    assert any("index" in a and "middle" in b or "middle" in a and "index" in b for a, b in names)


def test_score_grows_with_penetration(world, hand):
    scores = []
    for deg in (-6, -8, -10, -12, -14):  # from first contact (about -5 deg) until the bones cross
        q = hand.rest_pose()
        q[hand.joint_names.index("middle_mcp_abd")] = np.radians(deg)
        scores.append(world.collision_score(q)[0])
    assert all(a < b for a, b in zip(scores, scores[1:])), scores


def test_fast_path_matches_all_pairs_reference(world, hand):
    poses = sample_poses(hand, 150, np.random.default_rng(3))[0]
    fast = world.collision_score(poses)
    checks = world.in_collision(poses)
    for q, s, c in zip(poses, fast, checks):
        pairs = world.closest_pairs_reference(q)
        deepest: dict = {}
        for a, b, d in pairs:
            deepest[(a, b)] = min(d, deepest.get((a, b), np.inf))
        ref = world.score_from_distances(np.array(list(deepest.values())))
        assert s == pytest.approx(ref, rel=1e-6, abs=1e-9)
        assert c == any(d < 0 for d in deepest.values())
    # random poses are a real mix of colliding and free ones
    assert 0.2 < checks.mean() < 0.8


def test_near_miss_scores_soft_penalty_but_is_not_a_collision(hand):
    """Close but not touching: the proximity term (p_soft − d_min) is positive, the pose is collision-free."""
    with CollisionWorld(hand, CollisionConfig(p_soft=0.01)) as w:
        lo, hi = 0.0, -12.0
        for _ in range(30):  # bisect the middle finger's abduction to the first contact
            mid = (lo + hi) / 2
            q = hand.rest_pose()
            q[hand.joint_names.index("middle_mcp_abd")] = np.radians(mid)
            lo, hi = (mid, hi) if not w.in_collision(q)[0] else (lo, mid)
        q = hand.rest_pose()
        q[hand.joint_names.index("middle_mcp_abd")] = np.radians(lo + 1.0)  # 1 degree before contact
        assert not w.in_collision(q)[0]
        assert 0 < w.collision_score(q)[0] <= 500 * 0.01


def test_batched_equals_single(world, hand):
    poses = sample_poses(hand, 12, np.random.default_rng(9))[0]
    batch = world.collision_score(poses)
    assert np.array_equal(batch, np.array([world.collision_score(q)[0] for q in poses]))


def test_bad_pose_raises(world):
    with pytest.raises(ValueError, match="shape"):
        world.collision_score(np.zeros(3))


def test_world_closes_its_pybullet_client(hand):
    import pybullet as p

    from studio.errors import ClosedError

    with CollisionWorld(hand) as w:
        client = w.client
        assert p.isConnected(client)
        assert not w.in_collision(hand.rest_pose())[0]
    assert not p.isConnected(client)
    w.close()  # closing twice is fine
    for query in (w.in_collision, w.collision_score, w.contacts, w.closest_pairs_reference):
        with pytest.raises(ClosedError, match="CollisionWorld was closed"):
            query(hand.rest_pose())


def test_pybullet_banner_never_reaches_stderr():
    """PyBullet prints a banner when first imported; a CLI error after a world is made must stay one line."""
    import subprocess
    import sys

    code = (
        "from studio.sim.physics import CollisionWorld\n"
        "with CollisionWorld() as w: print(w.in_collision(w.hand.rest_pose())[0])"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "False" and out.stderr == "", out.stderr
