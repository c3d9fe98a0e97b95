"""Retrieval: an index over the aligned shadows of many collision-free self-exploration poses, queried in
milliseconds. Its best distinct poses are the studio's first answer and the seeds of the gradient search.

Building: the self-exploration sampler (:func:`studio.sim.sampling.sample_poses`) draws poses, the collision world
keeps the collision-free ones, the renderer casts their shadows at the model's resolution and each shadow is
crop-aligned like the image loss does (:func:`studio.imitate.rendered_loss.crop_batch`) at ``crop × crop``,
thresholded at 0.5 and bit-packed: ``crop = 32`` → 128 bytes a pose. Querying: the target is cropped the same way and
every entry is ranked by the pixel base loss ``w_mae·MAE + w_iou·(1 − IoU)`` of the binary crops (one AND and one
popcount per 64 pixels), then the ``shortlist`` best are rendered and scored exactly by the target's loss and the
best *distinct* poses (max joint distance ≥ ``min_dist``) are returned, best first.

The index depends only on the hand, the rig and :class:`RetrievalConfig` (:func:`index_key`);
:func:`studio.imitate.index_cache.cached_index` keeps it in ``studio.home.cache_dir()/retrieval/`` (built once per
machine, by one process at a time, ~30 s for 200,000 poses on 2 cores).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from numba import njit, prange

from studio.atomic import write_with
from studio.errors import ProgressFn, report, stopped
from studio.imitate.config import LossConfig
from studio.imitate.index_chunks import IndexChunkTask, pack_crops
from studio.learn.fanout import FanoutConfig, fan_out
from studio.sim.hand import Hand
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses
from studio.sim.shadow import ShadowRenderer

log = logging.getLogger(__name__)
FORMAT = 1  # bump when the file layout or the build changes
COLLISION_FREE_SHARE = 0.45  # about this share of sampled poses is collision-free (a spread build's round size)


@dataclass(frozen=True)
class RetrievalConfig:
    """How the retrieval index is built and queried."""

    size: int = 200_000  # collision-free self-exploration poses in the index [1, ∞)
    crop: int = 32  # side of the binary aligned crops the index ranks by, pixels (a multiple of 8) [8, ∞)
    shortlist: int = 256  # best-ranked poses rendered and scored exactly per query [1, ∞)
    min_dist: float = 0.3  # returned poses differ by at least this much on some joint, rad [0, ∞)
    pad: float = LossConfig.pad  # crop padding, pixels of a 256-pixel image (as the image loss)
    seed: int = 0  # sampler seed of the index poses [0, ∞)
    chunk: int = 16384  # poses sampled, collision-checked and rendered at once while building [1, ∞)

    def __post_init__(self) -> None:
        if self.size < 1 or self.shortlist < 1 or self.chunk < 1:
            raise ValueError("retrieval size, shortlist and chunk must be ≥ 1")
        if self.crop < 8 or self.crop % 8:
            raise ValueError(f"retrieval crop must be a multiple of 8 and ≥ 8, got {self.crop}")


@dataclass
class Retrieved:
    """What a query returns (plain data): distinct poses, best first, all collision-free."""

    theta: np.ndarray  # (K, 21) rad
    loss: np.ndarray  # (K,) their exact rendered-shadow losses under the query's loss
    seconds: float  # wall time of the query


class RetrievalIndex:
    """Poses ``theta (N, 21)`` float32 and their packed crops ``bits (N, W)`` uint64 (module docstring)."""

    def __init__(self, theta: np.ndarray, bits: np.ndarray, cfg: RetrievalConfig, key: str):
        self.theta = theta  # (N, 21) float32 rad, collision-free
        self.bits = bits  # (N, W) uint64 packed binary crops
        self.area = np.bitwise_count(bits).sum(axis=1, dtype=np.int32)  # (N,) shadow pixels of each crop
        self.cfg = cfg
        self.key = key  # what the index was built from (hand, rig, config): its cache name

    def __len__(self) -> int:
        return len(self.theta)

    @classmethod
    def build(
        cls,
        renderer: ShadowRenderer,
        cfg: RetrievalConfig | None = None,
        world: CollisionWorld | None = None,
        progress: ProgressFn | None = None,
        cancel: threading.Event | None = None,
        fanout: FanoutConfig | None = None,
    ) -> RetrievalIndex | None:
        """Sample, keep the collision-free, render and pack until ``cfg.size`` poses; stage "index" after every
        chunk (step: poses packed, of ``cfg.size``). ``cancel`` is checked before every chunk: once set, the build
        stops and returns None. ``fanout`` spreads the chunks over local processes or Ray actors
        (:mod:`studio.learn.fanout`): they are drawn here in the same order, so the index is the same (stage "index"
        after every round of chunks)."""
        cfg = cfg or RetrievalConfig()
        hand, fanout = renderer.hand, fanout or FanoutConfig()
        task = IndexChunkTask(hand, renderer.rig, cfg.crop, cfg.pad)
        rng = np.random.default_rng(cfg.seed)
        thetas, bits, done = [], [], 0
        if fanout.workers == 1 and not fanout.ray:  # in this process: one chunk after another
            task.setup(world)
            try:
                while done < cfg.size:
                    if stopped(cancel):
                        return None
                    kept, packed = task(sample_poses(hand, cfg.chunk, rng)[0])
                    thetas.append(kept[: cfg.size - done])
                    bits.append(packed[: cfg.size - done])
                    done += len(thetas[-1])
                    report(progress, "index", done, cfg.size)
            finally:
                task.close()
        while done < cfg.size:  # spread: rounds of chunks drawn here in the same order, so the same index
            need = max(fanout.workers, math.ceil(1.25 * (cfg.size - done) / (cfg.chunk * COLLISION_FREE_SHARE)))
            chunks = [sample_poses(hand, cfg.chunk, rng)[0] for _ in range(need)]
            got = fan_out(task, chunks, fanout, cancel=cancel)
            if stopped(cancel):
                return None
            for k in range(len(chunks)):
                if done < cfg.size:
                    thetas.append(got[k][0][: cfg.size - done])
                    bits.append(got[k][1][: cfg.size - done])
                    done += len(thetas[-1])
            report(progress, "index", done, cfg.size)
        return cls(np.concatenate(thetas), np.concatenate(bits), cfg, index_key(hand, renderer, cfg))

    def rank(self, target: np.ndarray, loss_cfg: LossConfig | None = None) -> np.ndarray:
        """Pixel base loss of every entry's crop against ``target (R, R)`` (binary crops) → ``(N,)`` float32."""
        lc = loss_cfg or LossConfig()
        t = pack_crops(np.asarray(target)[None] > 0.5, self.cfg.crop, self.cfg.pad)[0]
        t_area = int(np.bitwise_count(t).sum())
        inter = np.bitwise_count(self.bits & t).sum(axis=1, dtype=np.int32)
        union = np.maximum(self.area + t_area - inter, 1)
        pixels = self.cfg.crop**2
        return (lc.w_mae * (union - inter) / pixels + lc.w_iou * (1.0 - inter / union)).astype(np.float32)

    def best(self, targets: np.ndarray, loss_cfg: LossConfig | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The best entry for each of several targets ``(A, R, R)``: its pixel base loss ``(A,)`` float64 and its row
        ``(A,)`` int64 — ``rank(t).min()`` and ``argmin`` per target (the reference), compiled, without the
        ``(N,)`` temporaries: what the roll search asks of every candidate angle."""
        lc = loss_cfg or LossConfig()
        t = pack_crops(np.asarray(targets) > 0.5, self.cfg.crop, self.cfg.pad)
        t_area = np.bitwise_count(t).sum(axis=1).astype(np.int64)
        return _best_rows(self.bits, self.area.astype(np.int64), t, t_area, lc.w_mae, lc.w_iou, float(self.cfg.crop**2))

    def query(
        self,
        target: np.ndarray,
        score: Callable[[np.ndarray], np.ndarray],
        k: int,
        loss_cfg: LossConfig | None = None,
    ) -> Retrieved:
        """The ``k`` best distinct poses for ``target (R, R)``: ``score(theta (S, 21)) → (S,)`` exact losses of the
        shortlist (e.g. render + :class:`~studio.imitate.rendered_loss.RenderedLoss`); best first."""
        t0 = time.perf_counter()
        rank = self.rank(target, loss_cfg)
        m = min(max(self.cfg.shortlist, k), len(self))
        rows = np.argpartition(rank, m - 1)[:m]
        theta = self.theta[rows].astype(np.float64)
        loss = np.asarray(score(theta), dtype=np.float64)
        order = np.argsort(loss, kind="stable")
        taken: list[int] = []
        for i in order:
            if all(np.abs(theta[i] - theta[j]).max() >= self.cfg.min_dist for j in taken):
                taken.append(int(i))
                if len(taken) == k:
                    break
        return Retrieved(theta[taken], loss[taken], time.perf_counter() - t0)

    def save(self, path: Path) -> None:
        """Write the index (atomically) as ``.npz``."""
        meta = json.dumps({"format": FORMAT, "key": self.key, "cfg": asdict(self.cfg)})
        write_with(Path(path), lambda f: np.savez(f, theta=self.theta, bits=self.bits, meta=np.array(meta)))

    @classmethod
    def load(cls, path: Path, key: str | None = None) -> RetrievalIndex | None:
        """Read an index; None when the file is missing, unreadable, of another format or (given ``key``) stale."""
        try:
            with np.load(Path(path)) as z:
                meta = json.loads(str(z["meta"]))
                if meta.get("format") != FORMAT or (key is not None and meta.get("key") != key):
                    return None
                return cls(z["theta"], z["bits"], RetrievalConfig(**meta["cfg"]), meta["key"])
        except (OSError, ValueError, KeyError, TypeError, EOFError):
            return None


@njit(inline="always")
def _popcount(x):
    """Set bits of a uint64 (SWAR)."""
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (x * np.uint64(0x0101010101010101)) >> np.uint64(56)


@njit(parallel=True, cache=True)
def _best_rows(bits, area, targets, t_area, w_mae, w_iou, pixels):
    """Per target ``(A, W)`` packed: the lowest pixel loss over ``bits (N, W)`` and its row (first on ties). The
    rows are cut into ``CHUNKS`` slices so that even one target runs on every core."""
    n_t, (n, n_w) = targets.shape[0], bits.shape
    step = (n + _CHUNKS - 1) // _CHUNKS
    part = np.full((n_t, _CHUNKS), np.inf)
    part_row = np.zeros((n_t, _CHUNKS), np.int64)
    for job in prange(n_t * _CHUNKS):
        a, c = job // _CHUNKS, job % _CHUNKS
        b, bi = np.inf, 0
        for i in range(c * step, min(n, (c + 1) * step)):
            inter = 0
            for w in range(n_w):
                inter += _popcount(bits[i, w] & targets[a, w])
            union = max(area[i] + t_area[a] - inter, 1)
            v = w_mae * (union - inter) / pixels + w_iou * (1.0 - inter / union)
            if v < b:
                b, bi = v, i
        part[a, c], part_row[a, c] = b, bi
    best = np.empty(n_t)
    row = np.empty(n_t, np.int64)
    for a in range(n_t):
        c = np.argmin(part[a])  # the first chunk holding the minimum: the first row on ties
        best[a], row[a] = part[a, c], part_row[a, c]
    return best, row


_CHUNKS = 16


def index_key(hand: Hand, renderer: ShadowRenderer, cfg: RetrievalConfig) -> str:
    """A short hash of what the index is built from: hand, rig, renderer ring, build and sampler settings."""
    from studio.sim.sampling import SamplerConfig

    build = {k: v for k, v in asdict(cfg).items() if k not in ("shortlist", "min_dist", "chunk")}
    text = json.dumps([FORMAT, hand.hash, renderer.rig.hash, renderer.ring_points, build, asdict(SamplerConfig())])
    return hashlib.sha256(text.encode()).hexdigest()[:16]
