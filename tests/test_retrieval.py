"""studio.imitate.retrieval: the index (fast popcount ranking against a slow reference, exact poses back, distinct
answers, the cache) and the first answer it gives the Imitator."""

from __future__ import annotations

import contextlib
import logging
import threading
import time

import numpy as np
import pytest

try:
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None

from studio.errors import Progress
from studio.home import LOCK_POLL_S as POLL_S
from studio.imitate.config import ImitateConfig, LossConfig, RefineConfig, SearchConfig, SweepConfig
from studio.imitate.index_cache import WAITING, cached_index, index_path
from studio.imitate.losses import ImageLoss
from studio.imitate.rendered_loss import RenderedLoss, crop_batch
from studio.imitate.retrieval import RetrievalConfig, RetrievalIndex, index_key, pack_crops
from studio.imitate.still import Imitator
from studio.learn.selfmodel import SelfModel, SelfModelConfig
from studio.sim.crop_pad import pad_pixels
from studio.sim.physics import CollisionWorld
from studio.sim.shadow import Rig, ShadowRenderer

CFG = RetrievalConfig(size=1500, chunk=700, shortlist=64, seed=3)


@pytest.fixture(scope="module")
def renderer(hand):
    return ShadowRenderer(hand, Rig(resolution=32))


@pytest.fixture(scope="module")
def index(renderer):
    return RetrievalIndex.build(renderer, CFG)


def _scorer(renderer, target):
    fast = RenderedLoss(ImageLoss(target, LossConfig(use_clip=False, crop_size=32)))
    return lambda theta: fast(renderer.render(theta, check=False))[0]


def test_index_holds_collision_free_poses_within_limits(hand, index):
    assert len(index) == CFG.size and index.theta.shape == (CFG.size, 21) and index.bits.shape == (CFG.size, 16)
    assert np.all(index.theta >= hand.lower - 1e-6) and np.all(index.theta <= hand.upper + 1e-6)
    with CollisionWorld(hand) as world:
        assert not world.in_collision(index.theta[::25].astype(float)).any()


def test_pack_crops_are_the_thresholded_aligned_crops(renderer, index):
    shadows = renderer.render(index.theta[:20].astype(float))
    crops = crop_batch(shadows, pad_pixels(CFG.pad, 32, 32), CFG.crop) > 0.5
    unpacked = np.unpackbits(pack_crops(shadows, CFG.crop, CFG.pad).view(np.uint8), axis=1)
    np.testing.assert_array_equal(unpacked[:, : CFG.crop**2].astype(bool), crops.reshape(20, -1))
    np.testing.assert_array_equal(pack_crops(shadows, CFG.crop, CFG.pad), index.bits[:20])


def test_rank_matches_a_slow_reference(renderer, index):
    target = renderer.render_one(index.theta[7].astype(float))
    rank = index.rank(target)
    lc = LossConfig()
    t = (crop_batch(target[None], pad_pixels(CFG.pad, 32, 32), CFG.crop) > 0.5).reshape(-1)
    rows = np.arange(0, len(index), 37)
    crops = crop_batch(renderer.render(index.theta[rows].astype(float)), pad_pixels(CFG.pad, 32, 32), CFG.crop) > 0.5
    for row, c in zip(rows, crops.reshape(len(rows), -1)):
        inter, union = np.sum(c & t), np.sum(c | t)
        ref = lc.w_mae * np.mean(c != t) + lc.w_iou * (1 - inter / max(union, 1))
        assert rank[row] == pytest.approx(ref, abs=1e-6)


def test_query_returns_the_exact_pose_of_a_rendered_target(renderer, index):
    for i in (0, 123, 1499):
        target = renderer.render_one(index.theta[i].astype(float))
        got = index.query(target, _scorer(renderer, target), k=8)
        assert got.loss[0] == pytest.approx(0.0, abs=1e-6)
        np.testing.assert_array_equal(got.theta[0], index.theta[i].astype(float))
        assert np.all(np.diff(got.loss) >= 0) and len(got.theta) == 8
        gaps = np.abs(got.theta[:, None] - got.theta[None]).max(axis=-1) + np.eye(8) * 9
        assert gaps.min() >= CFG.min_dist  # distinct poses, as documented


def test_save_load_and_the_cache(tmp_path, renderer, index):
    path = tmp_path / "index.npz"
    index.save(path)
    back = RetrievalIndex.load(path, index.key)
    np.testing.assert_array_equal(back.theta, index.theta)
    np.testing.assert_array_equal(back.bits, index.bits)
    assert back.cfg == index.cfg
    assert RetrievalIndex.load(path, "another key") is None  # stale: rebuilt by cached_index
    assert RetrievalIndex.load(tmp_path / "missing.npz") is None
    (tmp_path / "broken.npz").write_bytes(b"not an npz")
    assert RetrievalIndex.load(tmp_path / "broken.npz") is None
    small = RetrievalConfig(size=300, chunk=300, seed=5)
    built = cached_index(renderer, small, folder=tmp_path / "cache")
    assert (tmp_path / "cache" / f"index-{index_key(renderer.hand, renderer, small)}.npz").is_file()
    assert cached_index(renderer, small, folder=tmp_path / "elsewhere") is built  # kept in this process


def test_a_cancelled_build_returns_nothing_and_saves_nothing(tmp_path, renderer):
    """A cancel set during the build stops it at the next chunk: no index, no file, and the next call builds."""
    cfg = RetrievalConfig(size=900, chunk=300, seed=17)
    cancel, seen = threading.Event(), []

    def progress(p: Progress):
        assert p.stage == "index" and p.total == 900
        seen.append(p.step)
        cancel.set()

    assert cached_index(renderer, cfg, folder=tmp_path, progress=progress, cancel=cancel) is None
    assert len(seen) == 1 and 0 < seen[0] <= 300 and list(tmp_path.glob("*.npz")) == []  # one chunk, then stopped
    built = cached_index(renderer, cfg, folder=tmp_path)
    assert len(built) == 900 and (tmp_path / f"index-{built.key}.npz").is_file()


@contextlib.contextmanager
def another_builder(path):
    """Hold the build lock of the index file ``path`` as another process building it would (``flock`` is per open
    file, so a second open file in this process is excluded as another process is)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_name(path.name + ".lock"), "a") as f:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        yield


def wait_for(what, timeout: float = 10.0) -> None:
    t0 = time.monotonic()
    while not what():
        assert time.monotonic() - t0 < timeout, "timed out"
        time.sleep(0.02)


@pytest.mark.skipif(fcntl is None, reason="no POSIX locks on this platform")
def test_a_process_waits_for_another_ones_build_and_loads_it_rather_than_building_twice(renderer, tmp_path, caplog):
    """Two processes wanting the index on a fresh machine (``project run --workers 2``, the notebook beside a
    terminal): while one builds, the other says once that it waits (stage "index", its item), then loads the file the
    builder saved; it never builds."""
    cfg = RetrievalConfig(size=300, chunk=300, seed=23)
    path = index_path(renderer, cfg, tmp_path)
    got, seen = [], []
    with another_builder(path), caplog.at_level(logging.INFO, logger="studio.imitate.index_cache"):
        waiter = threading.Thread(target=lambda: got.append(cached_index(renderer, cfg, tmp_path, seen.append)))
        waiter.start()
        wait_for(lambda: seen)
        assert (seen[0].stage, seen[0].step, seen[0].total, seen[0].item) == ("index", 0, 300, WAITING)
        time.sleep(3 * POLL_S)
        assert waiter.is_alive() and not got and not path.exists()  # still waiting, building nothing
        built = RetrievalIndex.build(renderer, cfg)  # the other process's build, saved before it lets go
        built.save(path)
    waiter.join(10)
    assert len(got) == 1 and got[0] is not None
    np.testing.assert_array_equal(got[0].theta, built.theta)
    assert seen[-1].step == seen[-1].total == 300 and seen[-1].item == WAITING
    said = [r.getMessage() for r in caplog.records]
    assert sum("waiting for it" in m for m in said) == 1
    assert not any("building the retrieval index once" in m for m in said)


@pytest.mark.skipif(fcntl is None, reason="no POSIX locks on this platform")
def test_a_cancel_while_waiting_for_another_build_returns_nothing(renderer, tmp_path):
    """Cancelled while another process builds: None within a poll, nothing built or saved; once the other process
    is gone without saving (killed), the next call takes the lock and builds."""
    cfg = RetrievalConfig(size=300, chunk=300, seed=29)
    path = index_path(renderer, cfg, tmp_path)
    cancel, got = threading.Event(), []
    with another_builder(path):
        waiter = threading.Thread(target=lambda: got.append(cached_index(renderer, cfg, tmp_path, cancel=cancel)))
        waiter.start()
        time.sleep(3 * POLL_S)
        cancel.set()
        waiter.join(2 * POLL_S + 1.0)
        assert not waiter.is_alive() and got == [None] and not path.exists()
    assert len(cached_index(renderer, cfg, tmp_path)) == 300 and path.is_file()


def test_a_cancel_while_the_index_is_built_ends_the_imitation_cancelled(hand, renderer, tmp_path, monkeypatch):
    """The first imitation on a machine builds the index (stage "index"); a cancel there returns at once, flagged
    cancelled, with no first answer and no refinement, and leaves no index behind."""
    monkeypatch.setenv("SHADOW_STUDIO_CACHE", str(tmp_path))
    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    cancel = threading.Event()

    def progress(p: Progress):
        if p.stage == "index":
            cancel.set()

    imitator = Imitator(model, loss_cfg=LossConfig(use_clip=False, crop_size=32), search=SearchConfig(batch=4),
                        retrieval=RetrievalConfig(size=1200, chunk=300, seed=19))  # fmt: skip
    with imitator:
        target = renderer.render_one(np.zeros(21))
        result = imitator.imitate(target, progress=progress, cancel=cancel)
    assert result.cancelled and result.first is None and result.refine is None and result.search.iterations == 0
    assert not any(tmp_path.rglob("*.npz"))


def test_config_is_checked():
    with pytest.raises(ValueError, match="multiple of 8"):
        RetrievalConfig(crop=30)
    with pytest.raises(ValueError, match="≥ 1"):
        RetrievalConfig(size=0)


@pytest.mark.slow
def test_imitator_answers_first_from_the_index_then_improves(hand, index, renderer):
    """The first reported pose is the retrieval's (collision-free, before any search step), the stages arrive in
    order, the search starts from the retrieved poses and the final answer is no worse than the first."""
    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    search = SearchConfig(batch=8, iterations=4, log_every=2)
    refine = RefineConfig(method="cmaes", restarts=1, steps=10)
    loss_cfg = LossConfig(use_clip=False, crop_size=32)
    imitator = Imitator(model, loss_cfg=loss_cfg, retrieval=index, search=search, refine=refine,
                        config=ImitateConfig(candidates=2))  # fmt: skip
    target = renderer.render_one(np.clip(index.theta[42] + 0.05, hand.lower, hand.upper))
    stages, poses = [], []
    with imitator:
        result = imitator.imitate(target, progress=lambda p: stages.append(p.stage), best_pose=poses.append)
    assert stages[0] == "retrieve" and stages.index("sweep") < stages.index("search") and stages[-1] == "refine"
    np.testing.assert_array_equal(poses[0], result.first.theta[0])
    assert result.timings["first_answer"] < result.seconds
    assert result.loss["total"] <= result.first.loss[0] + 1e-9
    swept = result.swept  # the block sweep: no pose worse than the retrieved one it started from, best first
    assert swept.theta.shape == result.first.theta.shape and np.all(np.diff(swept.loss) >= 0)
    assert swept.loss[0] <= result.first.loss[0] + 1e-12 and result.unrefined_loss["total"] <= swept.loss[0] + 1e-9
    with CollisionWorld(hand) as world:
        assert not world.in_collision(swept.theta).any()
    assert result.collision_free
    assert result.search.batch_theta.shape == (8, 21)


def test_sweep_with_clip_scores_draws_by_pixels_and_reports_the_full_loss(hand, index, renderer):
    """With CLIP on, the swept poses come back scored under the full loss (CLIP included), best first."""
    from studio.imitate.clip_loss import tiny_clip

    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    loss_cfg = LossConfig(use_clip=True, crop_size=32)
    clip = tiny_clip(seed=0)
    imitator = Imitator(model, loss_cfg=loss_cfg, clip=clip, retrieval=index, search=SearchConfig(batch=4,
                        iterations=1), config=ImitateConfig(candidates=1), sweep=SweepConfig(starts=2, draws=64,
                        wrist_draws=16, passes=1))  # fmt: skip
    target = renderer.render_one(np.clip(index.theta[9] + 0.1, hand.lower, hand.upper))
    with imitator:
        result = imitator.imitate(target, refine=False)
        full = imitator.refiner.score(imitator.loss_fn(target), result.swept.theta)[0]
    np.testing.assert_allclose(result.swept.loss, full, rtol=1e-5, atol=1e-6)
    assert np.all(np.diff(result.swept.loss) >= 0)
