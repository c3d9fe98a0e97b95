"""Building the retrieval index in pieces: a chunk of sampled poses → its collision-free poses and their
bit-packed aligned crops (:class:`IndexChunkTask`, a :mod:`studio.learn.fanout` task), so that the chunks of one
build can run in this process, on local processes or on Ray actors and give the same index
(:meth:`studio.imitate.retrieval.RetrievalIndex.build`)."""

from __future__ import annotations

from typing import Any

import numpy as np

from studio.imitate.rendered_loss import crop_batch
from studio.sim.crop_pad import pad_pixels
from studio.sim.hand import Hand
from studio.sim.shadow import Rig, ShadowRenderer

__all__ = ["IndexChunkTask", "pack_crops"]


def pack_crops(shadows: np.ndarray, crop: int, pad: float) -> np.ndarray:
    """Binary shadows ``(B, R, R)`` uint8 → bit-packed aligned crops ``(B, crop²/64)`` uint64 (pixel > 0.5)."""
    s = np.ascontiguousarray(shadows, dtype=np.uint8)
    crops = crop_batch(s, pad_pixels(pad, *s.shape[1:]), crop) > 0.5
    packed = np.packbits(crops.reshape(len(s), -1), axis=1)
    pad_bytes = (-packed.shape[1]) % 8
    if pad_bytes:
        packed = np.pad(packed, ((0, 0), (0, pad_bytes)))
    return np.ascontiguousarray(packed).view(np.uint64)


class IndexChunkTask:
    """``task(theta (C, 21) rad) → (kept (K, 21) float32, bits (K, crop²/64) uint64)``: the chunk's collision-free
    poses, in order, and their packed crops; set up once per worker (a renderer of ``rig`` and a collision world)."""

    def __init__(self, hand: Hand, rig: Rig, crop: int, pad: float):
        self.hand, self.rig, self.crop, self.pad = hand, rig, crop, pad
        self._held: Any = None

    def __getstate__(self) -> dict:  # a worker gets the recipe, never this process's renderer
        return self.__dict__ | {"_held": None}

    def setup(self, world: Any = None) -> None:
        """Make the renderer and a collision world (``world``: use the caller's, which stays theirs)."""
        from studio.sim.physics import CollisionWorld

        self._held = ShadowRenderer(self.hand, self.rig), world or CollisionWorld(self.hand), world is None

    def close(self) -> None:
        if self._held is not None and self._held[2]:
            self._held[1].close()
        self._held = None

    def __call__(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self._held is None:
            raise RuntimeError("IndexChunkTask.setup() was not called")
        renderer, world, _ = self._held
        kept = theta[~world.in_collision(theta, check=False)]
        return kept.astype(np.float32), pack_crops(renderer.render(kept, check=False), self.crop, self.pad)
