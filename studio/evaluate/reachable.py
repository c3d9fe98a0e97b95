"""Reachable targets: shadows the hand can cast exactly, for measuring the optimiser apart from the hand's reach.

On a real target (a letter, an animal) the loss that remains is part optimiser, part hand: no pose of this hand
may cast that outline. A reachable target takes the second part out. It is the shadow of a known collision-free
pose, drawn like self-exploration (:func:`~studio.sim.sampling.sample_poses`), rendered at a fine resolution and
framed like a loaded image (:func:`~studio.targets.images.square_frame`: its box plus the target margin,
area-resampled and thresholded), so it is as sharp as a target file, not a copy of a model-resolution render. The
known pose's own rendered shadow, scored against it, is the floor any method can reach at the model's resolution
(the rest is resampling); :func:`reach_summary` reports a method against it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from studio.sim.hand import Hand
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import SamplerConfig, sample_poses
from studio.sim.shadow import Rig, ShadowRenderer
from studio.targets.images import TargetConfig, shadow_box, square_frame


@dataclass(frozen=True)
class ReachableConfig:
    """How reachable targets are drawn."""

    count: int = 12  # targets [1, 10000]
    seed: int = 7  # seed of the pose draws [0, 4294967295]
    fine: int = 1024  # side, pixels, of the render the target is framed from (sharper than the model's) [8, 8192]
    sampler: SamplerConfig = field(default_factory=SamplerConfig)  # the self-exploration mix the poses are drawn from

    def __post_init__(self) -> None:
        if self.count < 1 or self.fine < 8:
            raise ValueError("reachable targets need count ≥ 1 and fine ≥ 8 pixels")


def reachable_targets(
    hand: Hand, world: CollisionWorld, size: int, cfg: ReachableConfig | None = None, rig: Rig | None = None,
    rolls: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """``cfg.count`` collision-free poses ``(N, 21)`` rad and their shadows as targets ``(N, size, size)`` uint8
    (1 = shadow), framed like :func:`~studio.targets.images.load_target` frames an image file; with ``rolls (N,)``
    rad, each as the mount rolled by its roll casts it (so roll auto has a known answer)."""
    cfg = cfg or ReachableConfig()
    rng = np.random.default_rng(cfg.seed)
    found: list[np.ndarray] = []
    while sum(len(f) for f in found) < cfg.count:
        theta, _ = sample_poses(hand, 4 * cfg.count, rng, cfg.sampler)
        found.append(theta[~world.in_collision(theta)])
    theta = np.concatenate(found)[: cfg.count]
    base = (rig or Rig()).with_resolution(cfg.fine)
    if rolls is None:
        fine = ShadowRenderer(hand, base).render(theta, check=False)
    else:
        fine = np.stack([ShadowRenderer(hand, base.with_roll(float(r))).render_one(th) for th, r in zip(theta, rolls)])
    margin = TargetConfig().margin
    targets = np.stack([square_frame(m, size, shadow_box(m), margin) for m in fine])
    return theta, targets


def reach_summary(losses: np.ndarray, floors: np.ndarray, tolerance: float = 0.02) -> dict[str, float]:
    """A method's IoU losses ``(N,)`` on reachable targets against the known poses' ``floors`` ``(N,)``: mean
    loss, mean floor, mean excess over the floor and the share of targets within ``tolerance`` of their floor."""
    losses, floors = np.asarray(losses, dtype=float), np.asarray(floors, dtype=float)
    excess = np.maximum(losses - floors, 0.0)
    return {
        "iou_loss": float(losses.mean()),
        "floor": float(floors.mean()),
        "excess": float(excess.mean()),
        "reached_pct": float(100.0 * np.mean(excess <= tolerance)),
    }
