"""The paper's baselines for still targets (DESIGN §4 "Baselines"): a random training image, the inverse CNN's
pose, and the nearest training image by base loss.

Random and Nearest Neighbour answer with a *training image* (a rendered shadow of a training pose, from the
shards) and that pose; the inverse CNN answers with a pose whose shadow is rendered. Nearest Neighbour aligns every
training image once per run (bounding-box crops at ``rank_size``, stored as uint8) and ranks all of them against a
target by the pixel part of the base loss (``w_mae·MAE + w_iou·(1 − IoU)``) in batches; the best ``shortlist``
are then scored exactly by the target's :class:`~studio.imitate.losses.ImageLoss` (full crop size, CLIP when on) and the
lowest base loss wins.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from studio.errors import ClosedError
from studio.evaluate.config import NNConfig
from studio.imitate.config import LossConfig
from studio.imitate.losses import ImageLoss, mae, soft_iou
from studio.learn.dataset import SPLITS
from studio.learn.inverse import InverseCNN
from studio.learn.shards import list_shards, read_shard
from studio.sim.crop import align
from studio.sim.hand import Hand, load_hand
from studio.sim.physics import CollisionWorld
from studio.sim.shadow import ShadowRenderer


@dataclass
class BaselineOutput:
    """One baseline's answer for one target (plain data)."""

    theta: np.ndarray  # (21,) rad, within the joint limits
    shadow: np.ndarray  # (H, W) uint8 shadow of that pose, 1 = shadow (training image or rendered)
    collides: bool  # the pose's skeleton penetrates itself
    seconds: float  # wall time of the answer
    index: int = -1  # row of the training set (Random, Nearest Neighbour); -1 otherwise
    roll: float = 0.0  # the mount roll the pose was chosen for, rad (its shadow is what that mount casts)


class TrainingSet:
    """A split of a shard folder in memory: poses ``(N, 21)``, bit-packed shadows and collision flags."""

    def __init__(self, theta: np.ndarray, packed: np.ndarray, collides: np.ndarray, resolution: int):
        self.theta = theta  # (N, 21) float32 rad
        self.packed = packed  # (N, ceil(R*R/8)) uint8 bit-packed shadows
        self.collides = collides  # (N,) bool skeleton self-collision
        self.resolution = resolution  # R, shadow side in pixels

    @classmethod
    def load(cls, folder: Path, hand: Hand | None = None, split: str = "train") -> TrainingSet:
        """Read ``split`` (the 0.7 training share by default) of every shard in ``folder`` (ShardError if bad)."""
        hand = hand or load_hand()
        lo, hi = SPLITS[split]
        parts, res = [], None
        for path in list_shards(folder):
            shard = read_shard(path, hand.hash)
            if res is not None and shard.resolution != res:
                raise ValueError(f"{path}: shards of {shard.resolution}² and {res}² are mixed in {folder}")
            res = shard.resolution
            rows = np.arange(int(round(lo * len(shard))), int(round(hi * len(shard))))
            parts.append((shard.theta[rows], shard.masks_packed[rows], shard.collides[rows]))
        theta, packed, collides = (np.concatenate(p) for p in zip(*parts))
        return cls(theta, packed, collides.astype(bool), int(res))

    def __len__(self) -> int:
        return len(self.theta)

    def shadows(self, rows: np.ndarray | slice) -> np.ndarray:
        """Unpacked shadows ``(n, R, R)`` uint8 of ``rows``."""
        r = self.resolution
        return np.unpackbits(self.packed[rows], axis=1, count=r * r).reshape(-1, r, r)

    def answer(self, i: int, seconds: float) -> BaselineOutput:
        return BaselineOutput(self.theta[i].astype(float), self.shadows(np.array([i]))[0], bool(self.collides[i]),
                              seconds, int(i))  # fmt: skip


class RandomImage:
    """Random baseline: a uniformly drawn training image; query ``k`` draws from the seed ``(seed, k)``, so a
    target's draw does not depend on which targets ran before it (or where)."""

    def __init__(self, data: TrainingSet, seed: int = 0):
        self.data, self.seed = data, seed

    def query(self, k: int = 0) -> BaselineOutput:
        t0 = time.perf_counter()
        i = int(np.random.default_rng([self.seed, k]).integers(len(self.data)))
        return self.data.answer(i, time.perf_counter() - t0)


class InverseBaseline:
    """Inverse-CNN baseline: predict θ from the target, clip to the limits, render its shadow.

    A world passed in stays the caller's; one made here is disconnected by ``close()`` (or the end of a ``with``
    block), after which ``query`` raises :class:`~studio.errors.ClosedError`.
    """

    def __init__(self, model: InverseCNN, renderer: ShadowRenderer, world: CollisionWorld | None = None):
        self.model, self.renderer = model, renderer
        self._owns_world = world is None
        self.world = world or CollisionWorld(renderer.hand)
        self.closed = False

    def close(self) -> None:
        """Disconnect the collision world if this baseline made it (idempotent)."""
        if self._owns_world:
            self.world.close()
        self.closed = True

    def __enter__(self) -> InverseBaseline:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def query(self, target: np.ndarray) -> BaselineOutput:
        """``target (H, W)`` mask → the CNN's pose, its rendered shadow and whether it collides."""
        if self.closed:
            raise ClosedError("this InverseBaseline was closed; make a new one (or query inside its `with` block)")
        t0 = time.perf_counter()
        theta = self.model.predict(target[None].astype(np.float32))[0]
        shadow = self.renderer.render_one(theta)
        collides = bool(self.world.in_collision(theta)[0])
        return BaselineOutput(theta, shadow, collides, time.perf_counter() - t0)


class NearestNeighbour:
    """Nearest training image by base loss (aligned crops precomputed once; module docstring)."""

    def __init__(self, data: TrainingSet, loss_cfg: LossConfig, cfg: NNConfig | None = None):
        self.data, self.loss_cfg, self.cfg = data, loss_cfg, cfg or NNConfig()
        crops = []
        for s in range(0, len(data), self.cfg.chunk):
            masks = torch.from_numpy(data.shadows(slice(s, s + self.cfg.chunk))).float()
            c, _ = align(masks, self.cfg.rank_size, loss_cfg.pad, loss_cfg.box_threshold)
            crops.append((c * 255).round().to(torch.uint8))
        self.crops = torch.cat(crops)  # (N, S, S) uint8 aligned training crops, 255 = shadow

    @torch.no_grad()
    def rank(self, target: np.ndarray) -> torch.Tensor:
        """Pixel base loss ``w_mae·MAE + w_iou·(1 − IoU)`` of every training image against ``target`` → ``(N,)``."""
        cfg = self.loss_cfg
        t, _ = align(torch.as_tensor(target).float(), self.cfg.rank_size, cfg.pad, cfg.box_threshold)
        out = []
        for s in range(0, len(self.crops), self.cfg.batch):
            p = self.crops[s : s + self.cfg.batch].float() / 255
            out.append(cfg.w_mae * mae(p, t) + cfg.w_iou * (1 - soft_iou(p, t, cfg.eps)))
        return torch.cat(out)

    @torch.no_grad()
    def query(self, target: np.ndarray, loss_fn: ImageLoss) -> BaselineOutput:
        """The training image with the lowest base loss under ``loss_fn`` among the ``shortlist`` best ranked."""
        t0 = time.perf_counter()
        k = min(self.cfg.shortlist, len(self.data))
        rows = torch.topk(self.rank(target), k, largest=False).indices.numpy()
        _, comps = loss_fn(torch.from_numpy(self.data.shadows(rows)).float())
        best = int(rows[int(torch.argmin(comps["base"]))])
        return self.data.answer(best, time.perf_counter() - t0)
