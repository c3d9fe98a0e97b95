"""studio.imitate.seeding: the retrieval + block-sweep seeds of a search from scratch, scored with the temporal term
when a sequence gives one, the rendered pool that keeps them, and sequences that seed the keyframes they search
from scratch (first keyframe; every keyframe when independent) while inheriting the rest."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from studio.errors import Progress
from studio.imitate.candidates import distinct_best, refine_best, rendered_pool
from studio.imitate.clip_loss import tiny_clip
from studio.imitate.config import ImitateConfig, LossConfig, RefineConfig, SearchConfig, SequenceConfig, SweepConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.retrieval import RetrievalConfig, RetrievalIndex
from studio.imitate.seeding import seed_poses
from studio.imitate.sequence import SequenceImitator
from studio.imitate.still import Imitator
from studio.learn.selfmodel import SelfModel, SelfModelConfig
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer

SWEEP = SweepConfig(starts=2, draws=48, wrist_draws=16, passes=1)
SEQ = SequenceConfig(
    first=SearchConfig(batch=8, iterations=4, lr=0.08),
    next=SearchConfig(batch=4, iterations=3, lr=0.08),
    refine=RefineConfig(method="cmaes", restarts=1, steps=6, popsize=8),
    candidates=1,
    expressive=False,
    retrieve=True,
    sweep=SWEEP,
)
LOSS = LossConfig(use_clip=False, crop_size=32)


@pytest.fixture(scope="module")
def renderer(hand):
    return ShadowRenderer(hand, Rig(resolution=32))


@pytest.fixture(scope="module")
def index(renderer):
    return RetrievalIndex.build(renderer, RetrievalConfig(size=1200, chunk=600, shortlist=48, seed=5))


@pytest.fixture(scope="module")
def imitator(hand, index):
    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    with Imitator(model, loss_cfg=LOSS, retrieval=index, search=SearchConfig(batch=8, iterations=4),
                  sweep=SWEEP) as im:  # fmt: skip
        yield im


@pytest.fixture(scope="module")
def targets(index, renderer, hand):
    """Three shadows of index poses moved a little (so no target is an index entry)."""
    rows = [11, 230, 871]
    return np.stack([renderer.render_one(np.clip(index.theta[r] + 0.07, hand.lower, hand.upper)) for r in rows])


def test_seeds_are_scored_with_the_temporal_term(imitator, index, targets):
    """With ``theta_prev`` the retrieved and swept poses are ranked by shadow + temporal term, as the search and
    refinement of that keyframe will score them, and the sweep never makes the best seed worse."""
    loss_fn = ImageLoss(targets[0], LOSS)
    prev = index.theta[500].astype(np.float64)
    refiner = imitator.refiner
    seeds = seed_poses(index, refiner, SWEEP, loss_fn, targets[0], 6, theta_prev=prev)
    total, comps = refiner.score(loss_fn, seeds.first.theta, prev)
    np.testing.assert_allclose(seeds.first.loss, total, rtol=1e-9)
    assert np.all(np.isfinite(comps["temporal"])) and np.all(comps["temporal"] > 0)
    np.testing.assert_allclose(seeds.swept.loss, refiner.score(loss_fn, seeds.swept.theta, prev)[0], rtol=1e-9)
    assert seeds.swept.loss[0] <= seeds.first.loss[0] + 1e-12 and np.all(np.diff(seeds.swept.loss) >= 0)
    assert seeds.best is seeds.swept and set(seeds.timings) == {"first_answer", "sweep"}
    plain = seed_poses(index, refiner, SWEEP, loss_fn, targets[0], 6)
    assert np.all(np.isnan(refiner.score(loss_fn, plain.first.theta)[1]["temporal"]))


def test_rendered_pool_keeps_the_seeds_and_drops_colliding_poses(imitator, index, targets, hand):
    loss_fn = ImageLoss(targets[1], LOSS)
    seeds = seed_poses(index, imitator.refiner, SweepConfig(starts=0), loss_fn, targets[1], 3)
    assert seeds.swept is None and seeds.best is seeds.first
    drawn, _ = sample_poses(hand, 64, rng=np.random.default_rng(4))
    with CollisionWorld(hand) as world:
        colliding = drawn[world.in_collision(drawn)][:2]  # random poses: about half penetrate themselves
    assert len(colliding) == 2
    pool, loss, best = rendered_pool(imitator.refiner, loss_fn, colliding, colliding[0], seeds.first)
    assert pool.shape == (5, 21) and np.all(np.isinf(loss[:2]))
    np.testing.assert_allclose(loss[2:], seeds.first.loss)
    np.testing.assert_array_equal(best, seeds.first.theta[0])
    _, _, fallback = rendered_pool(imitator.refiner, loss_fn, colliding, colliding[0])
    np.testing.assert_array_equal(fallback, colliding[0])  # nothing collision-free: the caller's fallback


def test_refine_best_keeps_the_lowest_loss_and_stops_on_cancel(imitator, index, targets):
    """Every distinct candidate is refined and the lowest loss kept; a cancel stops before the next candidate."""
    loss_fn = ImageLoss(targets[0], LOSS)
    pool = seed_poses(index, imitator.refiner, SweepConfig(starts=0), loss_fn, targets[0], 6).first
    cfg = RefineConfig(method="cmaes", restarts=1, steps=4, popsize=6)

    best = refine_best(imitator.refiner, loss_fn, pool.theta, pool.loss, 3, cfg)
    each = [imitator.refiner.refine(loss_fn, t, cfg) for t in distinct_best(pool.theta, pool.loss, 3)]
    assert len(each) == 3 and best.loss == min(r.loss for r in each) and best.collision_free
    assert best.loss <= pool.loss[0] + 1e-12  # refinement never returns worse than its start
    cancel, calls = threading.Event(), []

    def stop_after_first(p: Progress):
        calls.append(p.step)
        cancel.set()

    first = refine_best(imitator.refiner, loss_fn, pool.theta, pool.loss, 3, cfg, stop_after_first, cancel)
    one = []
    imitator.refiner.refine(loss_fn, distinct_best(pool.theta, pool.loss, 1)[0], cfg, lambda *a: one.append(a))
    assert first is not None and np.array_equal(first.theta, each[0].theta) and len(calls) == len(one)  # one only
    assert refine_best(imitator.refiner, loss_fn, pool.theta, pool.loss, 3, cfg, cancel=cancel) is None
    assert refine_best(imitator.refiner, loss_fn, pool.theta[:0], pool.loss[:0], 3, cfg) is None


def test_pixel_only_is_the_loss_without_clip(targets):
    plain = ImageLoss(targets[0], LOSS)
    assert plain.pixel_only() is plain
    with_clip = ImageLoss(targets[0], LossConfig(use_clip=True, crop_size=32), tiny_clip(seed=0))
    twin = with_clip.pixel_only()
    assert twin.clip is None and not twin.cfg.use_clip and with_clip.clip is not None
    shadows = np.stack([targets[1], targets[2]]).astype(np.float32)
    np.testing.assert_allclose(twin(shadows)[0].numpy(), plain(shadows)[0].numpy(), rtol=1e-6)
    assert not np.allclose(with_clip(shadows)[0].numpy(), plain(shadows)[0].numpy())


def test_with_clip_the_sweep_reports_no_pixel_loss_only_the_full_one(imitator, index, targets):
    """With CLIP on the sweep ranks its draws by the pixel terms: the progress it reports carries no loss until
    the swept poses are re-scored, and then the full loss of the best, the number the search goes on from."""
    loss_fn = ImageLoss(targets[2], LossConfig(use_clip=True, crop_size=32), tiny_clip(seed=0))
    heard = []
    seeds = seed_poses(index, imitator.refiner, SWEEP, loss_fn, targets[2], 4, progress=heard.append)
    assert all(isinstance(p, Progress) for p in heard) and heard[0].stage == "retrieve"
    sweep = [p for p in heard if p.stage == "sweep"]
    assert len(sweep) >= 3 and all(np.isnan(p.best) for p in sweep[:-1])
    assert sweep[-1].best == pytest.approx(seeds.swept.loss[0]) and sweep[-1].step == sweep[-1].total
    np.testing.assert_allclose(seeds.swept.loss, imitator.refiner.score(loss_fn, seeds.swept.theta)[0], rtol=1e-6)
    heard.clear()
    seed_poses(index, imitator.refiner, SWEEP, ImageLoss(targets[2], LOSS), targets[2], 4,
               progress=heard.append)  # fmt: skip
    assert all(np.isfinite(p.best) for p in heard)  # without CLIP every report has the loss


def _stages(seq, targets, cfg, **kw):
    stages, poses = [], []
    result = seq.imitate(targets, cfg=cfg, progress=lambda p: stages.append(p.stage), best_pose=poses.append, **kw)
    return result, stages, poses


def test_sequential_seeds_the_first_keyframe_and_inherits_the_rest(imitator, targets, hand):
    seq = SequenceImitator(cfg=SEQ, imitator=imitator)
    result, stages, poses = _stages(seq, targets, SEQ)
    assert [s for s in stages if s.endswith(("retrieve", "sweep"))][:1] == ["keyframe 1/3: retrieve"]
    later = {s.split(": ")[1] for s in stages if not s.startswith("keyframe 1/3")}
    assert "keyframe 1/3: sweep" in stages and later == {"search", "refine"}  # inherited: no seeds
    assert stages.index("keyframe 1/3: sweep") < stages.index("keyframe 1/3: search")
    first = result.keyframes[0]
    assert first.timings["seed"] > 0 and [k.timings["seed"] for k in result.keyframes[1:]] == [0.0, 0.0]
    assert len(result.keyframes) == 3 and all(k.collision_free for k in result.keyframes)
    with CollisionWorld(hand) as world:
        assert not world.in_collision(result.thetas).any()
    assert np.all(result.thetas >= hand.lower - 1e-9) and np.all(result.thetas <= hand.upper + 1e-9)
    # never worse than the first answer: the seeds stay in the pool that picks the unrefined pose
    retrieved = seed_poses(imitator.retrieval_index(), imitator.refiner, SweepConfig(starts=0),
                           ImageLoss(targets[0], LOSS), targets[0], SEQ.first.batch)  # fmt: skip
    assert first.loss["total"] <= retrieved.first.loss[0] + 1e-9


def test_independent_seeds_every_keyframe(imitator, targets):
    cfg = SequenceConfig(**{**SEQ.__dict__, "mode": "independent"})
    result, stages, _ = _stages(SequenceImitator(cfg=cfg, imitator=imitator), targets, cfg)
    assert [s for s in stages if s.endswith(": retrieve")] == [f"keyframe {k}/3: retrieve" for k in (1, 2, 3)]
    assert all(k.timings["seed"] > 0 for k in result.keyframes)
    plain, stages, _ = _stages(SequenceImitator(cfg=cfg, imitator=imitator), targets,
                               SequenceConfig(**{**cfg.__dict__, "retrieve": False}))  # fmt: skip
    assert not any(s.endswith((": retrieve", ": sweep")) for s in stages)  # the paper's sampled batches
    assert len(plain.keyframes) == 3
    unswept = SequenceConfig(**{**cfg.__dict__, "sweep": SweepConfig(starts=0)})  # the sequence's sweep, not the
    _, stages, _ = _stages(SequenceImitator(cfg=unswept, imitator=imitator), targets[:1], unswept)  # imitator's
    assert "retrieve" in stages and not any(s.endswith("sweep") for s in stages)  # one keyframe: plain stages


def test_a_keyframe_retrieves_as_many_seeds_as_its_own_search_batch(imitator, targets):
    """The first keyframe's search batch (12 here) is filled with retrieved poses, not the imitator's (8)."""
    loss_fn = ImageLoss(targets[0], LOSS)
    assert len(imitator.seed(loss_fn, targets[0]).first.theta) == imitator.search_cfg.batch == 8
    assert len(imitator.seed(loss_fn, targets[0], k=12).first.theta) == 12
    cfg = SequenceConfig(**{**SEQ.__dict__, "first": SearchConfig(batch=12, iterations=4, lr=0.08)})
    asked, seed = [], imitator.seed

    def counted(*a, **kw):  # the real Imitator.seed, its seeds counted
        seeds = seed(*a, **kw)
        asked.append(len(seeds.first.theta))
        return seeds

    imitator.seed = counted
    try:
        SequenceImitator(cfg=cfg, imitator=imitator).imitate(targets[:1], cfg=cfg)
    finally:
        del imitator.seed
    assert asked == [12]


def test_cancel_during_the_seeds_leaves_no_half_keyframe(imitator, targets):
    cancel = threading.Event()

    def progress(p: Progress):
        if p.stage.endswith("sweep"):
            cancel.set()

    result = SequenceImitator(cfg=SEQ, imitator=imitator).imitate(targets, cfg=SEQ, progress=progress, cancel=cancel)
    assert result.cancelled and result.keyframes == []


def test_retrieve_needs_an_imitator_with_retrieval(hand, index):
    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    with Imitator(model, loss_cfg=LOSS, retrieval=index, config=ImitateConfig(retrieve=False)) as im:
        with pytest.raises(ValueError, match="retrieval index"):
            SequenceImitator(cfg=SEQ, imitator=im).imitate(np.ones((1, 32, 32), np.uint8), cfg=SEQ)


def test_cancel_while_the_index_is_built_leaves_no_keyframe(imitator, tmp_path, monkeypatch, targets):
    """The first video on a machine builds the retrieval index under "keyframe 1/K: index"; a cancel there stops it
    (nothing saved) and the sequence returns cancelled with no keyframe."""
    monkeypatch.setenv("SHADOW_STUDIO_CACHE", str(tmp_path))
    cancel = threading.Event()
    stop_at_index = lambda p: cancel.set() if p.stage == "keyframe 1/3: index" else None  # noqa: E731
    with Imitator(imitator.model, loss_cfg=LOSS, retrieval=RetrievalConfig(size=1200, chunk=300, seed=23)) as im:
        seq = SequenceImitator(cfg=SEQ, imitator=im)
        result = seq.imitate(targets, cfg=SEQ, progress=stop_at_index, cancel=cancel)
    assert result.cancelled and result.keyframes == [] and not any(tmp_path.rglob("*.npz"))
