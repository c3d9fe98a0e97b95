"""studio.imitate.cmaes and the refiner's CMA-ES method: convergence, bounds, collision-free answers."""

from __future__ import annotations

import numpy as np
import pytest

from studio.imitate.cmaes import CMAES
from studio.imitate.config import CPU_REFINE, LossConfig, RefineConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer


def _minimise(f, es: CMAES, generations: int) -> float:
    best = np.inf
    for _ in range(generations):
        x = es.ask()
        assert np.all(x >= es.lower) and np.all(x <= es.upper)
        fx = np.array([f(v) for v in x])
        best = min(best, fx.min())
        es.tell(x, fx)
    return best


def test_converges_on_an_ill_conditioned_ellipsoid():
    n = 21
    scale = 10.0 ** (np.arange(n) / (n - 1) * 2)  # condition number 10⁴
    opt = np.linspace(-0.5, 0.5, n)
    f = lambda x: float(np.sum(scale * (x - opt) ** 2))  # noqa: E731
    es = CMAES(np.zeros(n), 0.3, -np.ones(n) * 3, np.ones(n) * 3, rng=np.random.default_rng(0))
    assert _minimise(f, es, 600) < 1e-8
    np.testing.assert_allclose(es.mean, opt, atol=1e-3)


def test_an_optimum_outside_the_bounds_ends_on_the_bound():
    lo, hi = -np.ones(5), np.ones(5)
    f = lambda x: float(np.sum((x - 2.0) ** 2))  # noqa: E731
    es = CMAES(np.zeros(5), 0.5, lo, hi, popsize=10, rng=np.random.default_rng(1))
    best = _minimise(f, es, 200)
    assert best == pytest.approx(5.0, abs=1e-3)  # (1 - 2)² on each of 5 joints
    np.testing.assert_allclose(es.mean, hi, atol=1e-2)


def test_arguments_are_checked():
    with pytest.raises(ValueError, match="sigma"):
        CMAES(np.zeros(3), 0.0, -np.ones(3), np.ones(3))
    with pytest.raises(ValueError, match="population"):
        CMAES(np.zeros(3), 0.1, -np.ones(3), np.ones(3), popsize=1)
    with pytest.raises(ValueError, match="method"):
        RefineConfig(method="annealing")


@pytest.mark.parametrize("seed", [0, 1])
def test_cmaes_refinement_recovers_a_nearby_pose_collision_free(hand, seed):
    """Started 0.15 rad from a rendered pose, CMA-ES brings the shadow back close to the target, never returning a
    colliding pose, and its reported loss is the rendered loss of its pose."""
    renderer = ShadowRenderer(hand, Rig(resolution=64))
    rng = np.random.default_rng(seed)
    with CollisionWorld(hand) as world:
        poses = sample_poses(hand, 64, rng)[0]
        q = poses[~world.in_collision(poses)][0]
    start = np.clip(q + rng.normal(0, 0.15, 21), hand.lower, hand.upper)
    loss_fn = ImageLoss(renderer.render_one(q), LossConfig(use_clip=False, crop_size=64))
    with Refiner(renderer) as refiner:
        res = refiner.refine(loss_fn, start, RefineConfig(method="cmaes", restarts=1, steps=120, seed=seed))
        assert res.collision_free and not refiner.world.in_collision(res.theta)[0]
        assert res.loss == pytest.approx(refiner.score(loss_fn, res.theta[None])[0][0])
    assert res.loss < 0.5 * res.start_loss and res.components["iou_loss"] < 0.15
    assert res.evaluations == 1 + 120 * 16
    assert np.all(res.theta >= hand.lower) and np.all(res.theta <= hand.upper)
    assert res.curve[-1][0] == 120 and CPU_REFINE.method == "cmaes"


def test_cmaes_refinement_climbs_out_of_collision(hand):
    renderer = ShadowRenderer(hand, Rig(resolution=64))
    rng = np.random.default_rng(4)
    with CollisionWorld(hand) as world:
        poses = sample_poses(hand, 64, rng)[0]
        hit = world.in_collision(poses)
        start, target_pose = poses[hit][0], poses[~hit][0]
    loss_fn = ImageLoss(renderer.render_one(target_pose), LossConfig(use_clip=False, crop_size=64))
    with Refiner(renderer) as refiner:
        seen = []
        cfg = RefineConfig(method="cmaes", restarts=2, steps=60, seed=0, log_every=10)
        res = refiner.refine(loss_fn, start, cfg, progress=seen.append)
        assert res.start_collides and res.collision_free, res.message
        assert [(p.stage, p.step, p.total) for p in seen] == [("refine", s, 120) for s in range(10, 121, 10)]
        assert seen[-1].best == res.loss  # both runs count on one bar: steps over restarts × steps
        assert not refiner.world.in_collision(res.theta)[0]
