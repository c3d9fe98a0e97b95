"""Shards: write/read round trip, resume, clear errors; torch streams."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from studio.errors import ShardError
from studio.learn.config import CollectConfig
from studio.learn.dataset import MANIFEST, OnTheFlyBatches, ShardStream, batch_loader, collect
from studio.learn.shards import list_shards, read_shard, shard_path, write_shard
from studio.sim.shadow import Rig, ShadowRenderer


@pytest.fixture(scope="module")
def small_dataset(tmp_path_factory, hand):
    out = tmp_path_factory.mktemp("ds")
    cfg = CollectConfig(n=250, shard_size=100, resolution=64)
    summary = collect(out, cfg, hand)
    return out, cfg, summary


def test_collect_writes_shards_with_metadata(small_dataset, hand):
    out, cfg, summary = small_dataset
    assert summary == {"written": 3, "skipped": 0, "samples": 250, "folder": str(out), "workers": "this process"}
    paths = list_shards(out)
    assert [p.name for p in paths] == ["shard_00000.npz", "shard_00001.npz", "shard_00002.npz"]
    shard = read_shard(paths[2], hand.hash, Rig(resolution=64).hash)
    assert len(shard) == 50 and shard.meta["hand_hash"] == hand.hash
    assert shard.meta["joint_names"] == hand.joint_names and shard.meta["resolution"] == 64
    manifest = json.loads((out / MANIFEST).read_text())
    assert manifest["collect"]["n"] == 250 and manifest["hand_hash"] == hand.hash


def test_shard_round_trip_is_exact(small_dataset, hand):
    out, cfg, _ = small_dataset
    shard = read_shard(shard_path(out, 1))
    again = ShadowRenderer(hand, cfg.rig()).render(shard.theta.astype(np.float64))
    assert np.array_equal(shard.masks(), again)
    assert shard.theta.dtype == np.float32 and shard.masks_packed.shape == (100, 64 * 64 // 8)


def test_resume_never_rewrites_finished_shards(small_dataset, hand):
    out, cfg, _ = small_dataset
    stamps = {p: p.stat().st_mtime_ns for p in list_shards(out)}
    before = read_shard(shard_path(out, 1))
    shard_path(out, 1).unlink()
    summary = collect(out, cfg, hand)
    assert summary["written"] == 1 and summary["skipped"] == 2
    for p, t in stamps.items():
        if p.name != "shard_00001.npz":
            assert p.stat().st_mtime_ns == t
    # the re-made shard is identical: shard k is drawn from the seed (seed, k)
    again = read_shard(shard_path(out, 1))
    assert np.array_equal(before.theta, again.theta) and np.array_equal(before.masks_packed, again.masks_packed)


def test_resume_is_deterministic(tmp_path, hand):
    cfg = CollectConfig(n=60, shard_size=30, resolution=32)
    collect(tmp_path / "a", cfg, hand)
    collect(tmp_path / "b", cfg, hand)
    for k in range(2):
        a, b = read_shard(shard_path(tmp_path / "a", k)), read_shard(shard_path(tmp_path / "b", k))
        assert np.array_equal(a.theta, b.theta) and np.array_equal(a.masks_packed, b.masks_packed)


def test_cancel_stops_between_shards(tmp_path, hand):
    import threading

    cancel = threading.Event()
    seen = []

    def progress(p):
        assert p.stage == "collect" and p.total == 90
        seen.append(p.step)
        cancel.set()

    summary = collect(tmp_path, CollectConfig(n=90, shard_size=30, resolution=32), hand, progress=progress,
                      cancel=cancel)  # fmt: skip
    assert summary["written"] == 1 and seen == [30]


def test_different_config_in_same_folder_is_refused(small_dataset, hand):
    out, cfg, _ = small_dataset
    with pytest.raises(ShardError, match="different dataset"):
        collect(out, CollectConfig(n=250, shard_size=100, resolution=128), hand)


def test_bad_shard_files_give_clear_errors(small_dataset, tmp_path, hand):
    out, _, _ = small_dataset
    good = shard_path(out, 0)
    truncated = tmp_path / "truncated.npz"
    truncated.write_bytes(good.read_bytes()[:500])
    with pytest.raises(ShardError, match="truncated.npz: unreadable or truncated"):
        read_shard(truncated)
    junk = tmp_path / "junk.npz"
    np.savez(junk, a=np.zeros(3))
    with pytest.raises(ShardError, match="not a shadow-studio shard"):
        read_shard(junk)
    with pytest.raises(ShardError, match="not the current hand"):
        read_shard(good, expect_hand_hash="0123456789abcdef")
    with pytest.raises(ShardError, match="not found"):
        read_shard(tmp_path / "absent.npz")
    with pytest.raises(ShardError, match="no shard files"):
        list_shards(tmp_path / "empty_dir_that_exists" if (tmp_path / "empty_dir_that_exists").mkdir() is None
                    else tmp_path)  # fmt: skip
    shard = read_shard(good)
    shard.theta = shard.theta.copy()
    shard.theta[0, 0] = np.nan
    write_shard(tmp_path / "nan.npz", shard)
    with pytest.raises(ShardError, match="NaN"):
        read_shard(tmp_path / "nan.npz")


def test_shard_stream_splits(small_dataset, hand):
    out, _, _ = small_dataset
    sizes = {s: len(ShardStream(out, s, hand=hand)) for s in ("train", "val", "test", "all")}
    assert sizes == {"train": 175, "val": 50, "test": 25, "all": 250}
    seen = 0
    for theta, masks in ShardStream(out, "val", batch_size=16, hand=hand):
        assert theta.shape[1] == 21 and masks.shape[1:] == (1, 64, 64)
        assert masks.dtype.is_floating_point and set(masks.unique().tolist()) <= {0.0, 1.0}
        seen += len(theta)
    assert seen == 50
    # splits are disjoint and together make up "all"
    rows = {s: _samples(ShardStream(out, s, hand=hand)) for s in ("train", "val", "test", "all")}
    keys = {s: set(r) for s, r in rows.items()}
    assert not keys["train"] & keys["val"] and not keys["train"] & keys["test"] and not keys["val"] & keys["test"]
    assert keys["train"] | keys["val"] | keys["test"] == keys["all"] and len(keys["all"]) == 250


def _samples(batches) -> dict[tuple, bytes]:
    """``{joint vector: its mask's bytes}`` of a stream of batches; fails on a repeated sample."""
    out: dict[tuple, bytes] = {}
    for theta, masks in batches:
        assert len(theta) == len(masks)
        for t, m in zip(theta, masks):
            key = tuple(t.tolist())
            assert key not in out, "sample read twice"
            out[key] = m.numpy().tobytes()
    return out


@pytest.mark.slow
@pytest.mark.filterwarnings("ignore:This DataLoader will create 4 worker processes")
@pytest.mark.parametrize("workers", [2, 4])  # 3 shards: 2 workers split the shards, 4 split each shard's rows
def test_dataloader_workers_read_each_sample_exactly_once(small_dataset, hand, workers):
    from torch.utils.data import IterableDataset

    out, _, _ = small_dataset
    for split, n in (("train", 175), ("val", 50), ("test", 25)):
        stream = ShardStream(out, split, batch_size=16, hand=hand)
        assert isinstance(stream, IterableDataset)
        single = _samples(ShardStream(out, split, batch_size=16, shuffle=False, hand=hand))
        assert len(single) == n
        loader = batch_loader(stream, num_workers=workers)
        orders = []
        for epoch in (0, 1):
            stream.set_epoch(epoch)
            batches = list(loader)
            assert _samples(batches) == single, f"{split}, epoch {epoch}: samples missing, extra or mispaired"
            orders.append(torch.cat([theta for theta, _ in batches]))
        if split == "train":  # (a val/test share of a shard fits in one batch, whose rows are kept sorted)
            assert not torch.equal(orders[0], orders[1]), "set_epoch did not reshuffle"


@pytest.mark.slow
def test_on_the_fly_workers_do_not_repeat_each_other(hand):
    """Also after this process has rendered on numba's OpenMP pool, which kills plainly forked workers."""
    ShadowRenderer(hand, Rig(resolution=32)).render(np.zeros((256, 21)))
    stream = OnTheFlyBatches(batch_size=4, resolution=32, num_batches=5, hand=hand)
    batches = list(batch_loader(stream, num_workers=2))
    assert len(batches) == 5 and len(_samples(batches)) == 20


def test_on_the_fly_batches(hand):
    batches = list(OnTheFlyBatches(batch_size=8, resolution=32, num_batches=3, hand=hand))
    assert len(batches) == 3
    theta, masks = batches[0]
    assert theta.shape == (8, 21) and masks.shape == (8, 1, 32, 32)
    again = ShadowRenderer(hand, Rig(resolution=32)).render(theta.double().numpy())
    assert np.array_equal(masks[:, 0].numpy().astype(np.uint8), again)


def test_a_failed_shard_write_keeps_the_old_shard(small_dataset, tmp_path):
    out, _, _ = small_dataset
    path = tmp_path / "shard_00000.npz"
    path.write_bytes(shard_path(out, 0).read_bytes())
    before = read_shard(path)
    broken = read_shard(path)
    broken.meta = {**broken.meta, "seed": object()}  # not JSON: the write fails after the temporary file exists
    with pytest.raises(TypeError):
        write_shard(path, broken)
    after = read_shard(path)
    assert np.array_equal(after.theta, before.theta) and after.meta == before.meta
    assert [p.name for p in tmp_path.iterdir()] == ["shard_00000.npz"]  # no temporary file left behind
