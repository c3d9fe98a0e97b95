"""Self-exploration data: collect (sample poses → render shadows → shards), stream shards to torch, or render
batches on the fly. Both streams are torch ``IterableDataset``s of whole batches whose DataLoader workers share the
work instead of repeating it; :func:`batch_loader` makes that DataLoader (workers started safely after rendering).

A dataset folder holds ``dataset.json`` (the collection config, rig and hand hash) and ``shard_#####.npz``
files (``studio.learn.shards``). Collection is resumable: shard ``k`` is drawn from the seed ``(seed, k)``, finished
shards are never rewritten, and re-running the same command continues where it stopped.
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
import threading
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader, IterableDataset, get_worker_info

from studio.atomic import write_json
from studio.errors import ProgressFn, ShardError, report
from studio.learn.config import CollectConfig
from studio.learn.fanout import FanoutConfig, fan_out
from studio.learn.shards import SHARD_FORMAT, Shard, list_shards, pack_masks, read_shard, shard_path, write_shard
from studio.sim.hand import Hand, load_hand
from studio.sim.sampling import SamplerConfig, sample_poses
from studio.sim.shadow import Rig, ShadowRenderer

log = logging.getLogger(__name__)
MANIFEST = "dataset.json"
SPLITS = {"train": (0.0, 0.7), "val": (0.7, 0.9), "test": (0.9, 1.0), "all": (0.0, 1.0)}  # share of each shard


def _manifest(cfg: CollectConfig, hand: Hand, sampler: SamplerConfig) -> dict:
    rig = cfg.rig()
    return {
        "format": SHARD_FORMAT,
        "collect": asdict(cfg),
        "sampler": asdict(sampler),
        "rig": rig.to_dict(),
        "rig_hash": rig.hash,
        "hand_hash": hand.hash,
        "joint_names": hand.joint_names,
    }


def make_shard(hand: Hand, renderer: ShadowRenderer, world, n: int, seed: int, index: int, sampler) -> Shard:
    """Draw and render one shard's samples (pure compute apart from the collision world)."""
    rng = np.random.default_rng([seed, index])
    theta, mode = sample_poses(hand, n, rng, sampler)
    masks = renderer.render(theta, check=False)
    collides = world.in_collision(theta, check=False)
    meta = {
        "format": SHARD_FORMAT,
        "rig": renderer.rig.to_dict(),
        "rig_hash": renderer.rig.hash,
        "hand_hash": hand.hash,
        "joint_names": hand.joint_names,
        "resolution": renderer.rig.resolution,
        "index": index,
        "seed": seed,
    }
    return Shard(theta.astype(np.float32), pack_masks(masks), mode, collides, meta)


class ShardTask:
    """Write shard ``k`` of a dataset folder (a :func:`studio.learn.fanout.fan_out` task): set up once per worker (the
    renderer and a collision world), then ``task(k) → (samples, written)``; an existing complete shard is kept."""

    def __init__(self, out: Path, cfg: CollectConfig, sampler: SamplerConfig, hand: Hand | None = None):
        self.out, self.cfg, self.sampler, self.hand = Path(out), cfg, sampler, hand
        self._renderer: ShadowRenderer | None = None
        self._world = None

    def __getstate__(self) -> dict:  # what a worker process gets: the recipe, not this process's renderer
        return self.__dict__ | {"_renderer": None, "_world": None}

    def setup(self) -> None:
        from studio.sim.physics import CollisionWorld

        self.hand = self.hand or load_hand()
        self._renderer = ShadowRenderer(self.hand, self.cfg.rig())
        self._world = CollisionWorld(self.hand)

    def close(self) -> None:
        if self._world is not None:
            self._world.close()
            self._world = None

    def __call__(self, k: int) -> tuple[int, bool]:
        if self._renderer is None:
            raise RuntimeError("ShardTask.setup() was not called")
        cfg, hand = self.cfg, self.hand
        n_k = min(cfg.shard_size, cfg.n - k * cfg.shard_size)
        path = shard_path(self.out, k)
        if path.exists():
            try:
                if len(read_shard(path, hand.hash, self._renderer.rig.hash)) == n_k:
                    return n_k, False
            except ShardError as e:
                log.warning("rewriting damaged shard: %s", e)
        write_shard(path, make_shard(hand, self._renderer, self._world, n_k, cfg.seed, k, self.sampler))
        return n_k, True


def collect(
    out: Path,
    cfg: CollectConfig | None = None,
    hand: Hand | None = None,
    sampler: SamplerConfig | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    fanout: FanoutConfig | None = None,
) -> dict:
    """Fill ``out`` with ``cfg.n`` samples in shards; resumes an interrupted run of the same config.

    ``fanout`` spreads the shards over local processes or Ray actors (:mod:`studio.learn.fanout`; default: this
    process); shard ``k`` is drawn from ``(seed, k)`` wherever it is made, so every way gives the same files (on a
    cluster, ``out`` must be a path every machine sees). Reports stage "collect" after each shard (step: samples
    done, of ``cfg.n``; shards already on disk count when reached); setting ``cancel`` stops after the shards being
    made (finished shards stay). Returns ``{"written", "skipped", "samples", "folder", "workers"}``.
    """
    cfg = cfg or CollectConfig()
    hand = hand or load_hand()
    sampler = sampler or SamplerConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    manifest = json.loads(json.dumps(_manifest(cfg, hand, sampler)))  # as it reads back from disk
    mpath = out / MANIFEST
    if mpath.exists():
        old = json.loads(mpath.read_text())
        if old != manifest:
            raise ShardError(
                f"{out} already holds a different dataset (config, rig or hand differ); "
                "use another --out folder or the same options as before"
            )
    else:
        write_json(mpath, manifest, sort_keys=True)
    fanout = fanout or FanoutConfig()
    task = ShardTask(out, cfg, sampler, hand if fanout.workers == 1 and not fanout.ray else None)
    samples = 0

    def counted(_k: int, result: tuple[int, bool]) -> None:
        nonlocal samples
        samples += result[0]
        report(progress, "collect", samples, cfg.n)

    done = fan_out(task, range(cfg.num_shards), fanout, cancel=cancel, on_result=counted)
    written = sum(w for _, w in done.values())
    return {"written": written, "skipped": len(done) - written, "samples": samples,
            "folder": str(out), "workers": fanout.where}  # fmt: skip


class ShardStream(IterableDataset):
    """Streams ``(theta (B, 21) float32, masks (B, 1, H, W) float32)`` torch batches from a shard folder.

    ``split`` takes the 0.7 / 0.2 / 0.1 train / val / test share of every shard (``"all"`` takes everything);
    shards are read one at a time, so memory stays at one shard (per worker). ``len()`` counts samples, not batches.

    A torch ``IterableDataset`` of whole batches (:func:`batch_loader` with ``num_workers=W``). An epoch
    yields every sample of the split exactly once however many workers read it: with at least ``W`` shards each
    worker reads whole shards (every ``W``-th of the epoch's shard order), with fewer every worker reads every shard
    and keeps every ``W``-th of its rows. Epoch ``k`` is shuffled from the seed ``(seed, k)``; iterating advances
    ``k``, but DataLoader workers iterate copies, so call ``set_epoch(k)`` before each epoch there (persistent
    workers advance their copies together).
    """

    def __init__(self, folder: Path, split: str = "train", batch_size: int = 64, shuffle: bool = True,
                 seed: int = 0, hand: Hand | None = None):  # fmt: skip
        if split not in SPLITS:
            raise ValueError(f"split must be one of {list(SPLITS)}, got {split!r}")
        if batch_size < 1:
            raise ValueError(f"batch_size must be positive, got {batch_size}")
        self.paths = list_shards(folder)
        self.split, self.batch_size, self.shuffle, self.seed = split, batch_size, shuffle, seed
        self.hand_hash = (hand or load_hand()).hash
        self.epoch = 0  # the next epoch's number: its shuffle is drawn from (seed, epoch)

    def set_epoch(self, epoch: int) -> None:
        """Make the next iteration epoch ``epoch`` (its shard and row order); needed with DataLoader workers."""
        self.epoch = int(epoch)

    def _rows(self, n: int) -> np.ndarray:
        lo, hi = SPLITS[self.split]
        return np.arange(int(round(lo * n)), int(round(hi * n)))

    def __len__(self) -> int:
        """Number of samples in this split (reads only shard metadata sizes)."""
        total = 0
        for p in self.paths:
            with np.load(p) as z:
                total += len(self._rows(len(z["theta"])))
        return total

    def __iter__(self) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        info = get_worker_info()
        worker, workers = (0, 1) if info is None else (info.id, info.num_workers)
        epoch = self.epoch
        self.epoch += 1
        order = np.random.default_rng([self.seed, epoch]).permutation(len(self.paths))
        if not self.shuffle:
            order = np.arange(len(self.paths))
        whole_shards = len(order) >= workers  # else split each shard's rows between the workers
        for i in order[worker::workers] if whole_shards else order:
            shard = read_shard(self.paths[i], self.hand_hash)
            rows = self._rows(len(shard))
            if self.shuffle:  # the same in every worker: the row split below stays disjoint
                rows = np.random.default_rng([self.seed, epoch, int(i)]).permutation(rows)
            if not whole_shards:
                rows = rows[worker::workers]
            for s in range(0, len(rows), self.batch_size):
                r = np.sort(rows[s : s + self.batch_size])
                theta = torch.from_numpy(shard.theta[r].astype(np.float32))
                masks = torch.from_numpy(shard.masks(r).astype(np.float32))[:, None]
                yield theta, masks


class OnTheFlyBatches(IterableDataset):
    """Endless (or ``num_batches``-long) stream of freshly sampled and rendered torch batches
    ``(theta (B, 21) float32, masks (B, 1, R, R) float32)``.

    In one process the poses are drawn from ``seed``; DataLoader worker ``w`` of ``W`` draws from ``(seed, w)``
    and makes every ``W``-th of the ``num_batches``, so workers never repeat each other's poses.
    """

    def __init__(self, batch_size: int = 64, resolution: int = 128, seed: int = 0, num_batches: int | None = None,
                 hand: Hand | None = None, sampler: SamplerConfig | None = None):  # fmt: skip
        self.hand = hand or load_hand()
        self.renderer = ShadowRenderer(self.hand, Rig(resolution=resolution))
        self.batch_size, self.seed, self.num_batches = batch_size, seed, num_batches
        self.sampler = sampler or SamplerConfig()

    def __iter__(self) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        info = get_worker_info()
        if info is None:
            rng, count = np.random.default_rng(self.seed), self.num_batches
        else:
            rng = np.random.default_rng([self.seed, info.id])
            count = None if self.num_batches is None else len(range(info.id, self.num_batches, info.num_workers))
        k = 0
        while count is None or k < count:
            theta, _ = sample_poses(self.hand, self.batch_size, rng, self.sampler)
            masks = self.renderer.render(theta, check=False)
            yield torch.from_numpy(theta.astype(np.float32)), torch.from_numpy(masks.astype(np.float32))[:, None]
            k += 1


def batch_loader(batches: IterableDataset, num_workers: int = 0, **kwargs) -> DataLoader:
    """A DataLoader over a stream of whole batches (:class:`ShardStream`, :class:`OnTheFlyBatches`) read by
    ``num_workers`` worker processes (0: in this process); ``kwargs`` go to the DataLoader.

    Workers start from a fork server (spawn where there is none), never by a plain fork: once this process has
    rendered, numba's OpenMP pool terminates every child forked from it ("fork() called from a process already using
    GNU OpenMP, this is unsafe"), which ``DataLoader(stream, num_workers=W)`` meets as a dead worker. The server
    imports this module once, so each worker starts in a fraction of a second.
    """
    context = None
    if num_workers:
        method = "forkserver" if "forkserver" in mp.get_all_start_methods() else "spawn"
        context = mp.get_context(method)
        if method == "forkserver":
            context.set_forkserver_preload([__name__])
    return DataLoader(batches, batch_size=None, num_workers=num_workers, multiprocessing_context=context, **kwargs)
