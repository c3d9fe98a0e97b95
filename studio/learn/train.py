"""Training the self-model with MAE on (pose, shadow) pairs, with the shared trainer (``studio.learn.trainer``):
from shards (0.7/0.2/0.1 split) or rendered on the fly, warm-up + cosine AdamW, periodic validation, atomic
checkpoints that resume exactly, CUDA when present.
"""

from __future__ import annotations

import threading

import torch

from studio.errors import ProgressFn
from studio.learn.config import TrainConfig
from studio.learn.pairs import Batch, Pairs
from studio.learn.selfmodel import SelfModel
from studio.learn.trainer import Replica, Task, fit
from studio.sim.hand import Hand, load_hand


@torch.no_grad()
def evaluate_mae(model: SelfModel, batches: list[Batch]) -> float:
    """Mean absolute error over held-out batches (pixel mean, then sample mean)."""
    was, device = model.training, next(model.parameters()).device
    model.eval()
    total, n = 0.0, 0
    for theta, masks in batches:
        pred = model(theta.to(device))
        total += (pred - masks.to(device)).abs().mean(dim=(1, 2, 3)).sum().item()
        n += len(theta)
    model.train(was)
    return total / max(n, 1)


def _mae(model: SelfModel, theta: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
    return (model(theta) - masks).abs().mean()


def train(
    cfg: TrainConfig,
    hand: Hand | None = None,
    resume: bool = False,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    replica: Replica | None = None,
) -> dict:
    """Train (or resume) a self-model; returns the metrics written into the checkpoint (``test_mae``,
    ``val_mae``, ...; see :func:`studio.learn.trainer.fit`, which says the stages reported, what ``cancel`` does and
    what a data-parallel ``replica`` does; :func:`studio.learn.ray_train.fit_on_ray` runs this on Ray Train)."""
    hand = hand or load_hand()
    mcfg = cfg.model_config()
    task = Task(
        build=lambda: SelfModel(mcfg, hand),
        loss=_mae,
        evaluate=evaluate_mae,
        metric="mae",
        pairs=lambda: Pairs(cfg, hand, mcfg.resolution, fit=True),
    )
    return fit(cfg, task, resume=resume, overwrite=overwrite, progress=progress, cancel=cancel, replica=replica)
