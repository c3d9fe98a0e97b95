"""Where the trainer's batches come from (:mod:`studio.learn.trainer`): ``(theta (B, 21) rad, shadows (B, 1, R, R))``
pairs from shards (0.7/0.2/0.1 split) or rendered on the fly (batch ``k`` drawn from the seed ``(seed, k)``, fixed
held-out validation and test sets), and the next batches made ahead in a background thread while the network steps.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from studio.errors import StudioError
from studio.learn.config import TrainerConfig
from studio.sim.hand import Hand
from studio.sim.sampling import sample_poses
from studio.sim.shadow import ShadowRenderer

Batch = tuple[torch.Tensor, torch.Tensor]  # theta (B, 21) float32 rad, shadows (B, 1, R, R) float32 (1 = shadow)
PREFETCH = 2  # training batches made ahead in a background thread while the network steps (the renderer is nogil)


def _fit(masks: torch.Tensor, res: int) -> torch.Tensor:
    """Area-downsample ``(B, 1, R, R)`` masks to ``res`` when R is a multiple of it."""
    R = masks.shape[-1]
    if R == res:
        return masks
    if R % res:
        raise StudioError(f"shards are {R}² but the model is {res}²: collect at {res} or a multiple of it")
    return F.avg_pool2d(masks, R // res)


class Pairs:
    """Training batches and held-out sets of ``(theta, shadows)`` pairs, from shards or the renderer.

    ``resolution``: the side of rendered shadows; with ``fit`` shard shadows are area-downsampled to it too (the
    self-model's output side), else shards keep their own side (the inverse CNN crops whatever it gets).
    """

    def __init__(self, cfg: TrainerConfig, hand: Hand, resolution: int, fit: bool = True):
        self.cfg, self.hand, self.res, self.fit = cfg, hand, resolution, fit
        if cfg.data:
            from studio.learn.shards import list_shards, read_shard

            meta = read_shard(list_shards(Path(cfg.data))[0], hand.hash).meta
            if fit:
                _fit(torch.zeros(1, 1, meta["resolution"], meta["resolution"]), resolution)  # fails early
            self.rig = meta["rig"] | ({"resolution": resolution} if fit else {})
        else:
            self.renderer = ShadowRenderer(hand, cfg.rig(resolution))
            self.rig = self.renderer.rig.to_dict()

    def _stream(self, split: str, shuffle: bool) -> Iterator[Batch]:
        from studio.learn.dataset import ShardStream

        stream = ShardStream(Path(self.cfg.data), split, self.cfg.batch_size, shuffle, self.cfg.seed, self.hand)
        for theta, masks in stream:
            yield theta, _fit(masks, self.res) if self.fit else masks

    def _rendered(self, n: int, seed: list[int], part: tuple[int, int] = (0, 1), raw: bool = False) -> Batch:
        """``n`` poses drawn from ``seed``, rows ``part[0]::part[1]`` of them rendered; ``raw``: the shadows as the
        renderer's uint8 (a quarter of the bytes to move to the device, cast there), else float32."""
        theta, _ = sample_poses(self.hand, n, np.random.default_rng(seed))
        theta = theta[part[0] :: part[1]]
        masks = torch.from_numpy(self.renderer.render(theta, check=False))[:, None]
        return torch.from_numpy(theta.astype(np.float32)), masks if raw else masks.float()

    def train_batches(self, start_step: int = 0, part: tuple[int, int] = (0, 1)) -> Iterator[Batch]:
        """Endless training batches; on the fly, batch ``k`` is drawn from ``(seed, k)`` so a resumed run continues
        the same stream (shards restart their shuffled epochs). ``part (r, W)``: rows ``r::W`` of every batch (a
        data-parallel replica's share; on the fly only those rows are rendered, and their shadows stay uint8 for
        :func:`fit` to cast on its device)."""
        r, w = part
        if self.cfg.data:
            while True:
                for theta, masks in self._stream("train", True):
                    yield theta[r::w], masks[r::w]
        step = start_step
        while True:
            yield self._rendered(self.cfg.batch_size, [self.cfg.seed, step], part, raw=True)
            step += 1

    def held_out(self, split: str) -> list[Batch]:
        """The ``"val"`` or ``"test"`` set as a list of batches (the same on every call)."""
        if self.cfg.data:
            return list(self._stream(split, False))
        theta, masks = self._rendered(self.cfg.eval_size, [self.cfg.seed, 10**9 + {"val": 1, "test": 2}[split]])
        return list(zip(theta.split(256), masks.split(256)))


class BatchesAhead:
    """The next ``PREFETCH`` items of ``source`` made in a background thread, in order (the same batches as
    ``source`` itself); a failure there is raised here at the item it replaced. ``close()`` ends the thread."""

    _END = object()

    def __init__(self, source: Iterator[Batch], depth: int = PREFETCH):
        self.queue: queue.Queue = queue.Queue(maxsize=depth)
        self.closed = threading.Event()
        self.thread = threading.Thread(target=self._fill, args=(source,), name="batches-ahead", daemon=True)
        self.thread.start()

    def _fill(self, source: Iterator[Batch]) -> None:
        try:
            for item in source:
                if not self._put(item):
                    return
        except BaseException as e:  # handed to the consumer, raised there
            self._put(e)
        self._put(self._END)

    def _put(self, item) -> bool:
        while not self.closed.is_set():
            try:
                self.queue.put(item, timeout=0.1)
                return True
            except queue.Full:
                continue
        return False

    def __next__(self) -> Batch:
        item = self.queue.get()
        if item is self._END:
            raise StopIteration
        if isinstance(item, BaseException):
            raise item
        return item

    def close(self) -> None:
        self.closed.set()
        self.thread.join(timeout=5)
