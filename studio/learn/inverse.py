"""The inverse-CNN baseline (DESIGN §4 "Baselines"): a shadow image → joint angles, trained with MSE.

The network sees the shadow the way the losses do: the bounding-box crop of its pixels, padded and made square
(:func:`studio.sim.crop.align`), so a target framed by :func:`studio.targets.images.load_target` and a
shadow in the rig's window look alike. ``crop (B, 1, S, S) → strided convs → FC → theta (B, 21) rad``; the output is
the joints' range centre plus a learnt offset, and predictions are clipped to the joint limits. It trains with the
shared trainer (``studio.learn.trainer``) on pairs rendered fresh every step or from shards; its checkpoints are
``studio.learn.checkpoint``'s (kind ``"inverse"``).
"""

from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import torch
from torch import nn

from studio.errors import ProgressFn
from studio.learn.checkpoint import Checkpoint, load_model
from studio.learn.config import InverseConfig, InverseTrainConfig
from studio.learn.pairs import Batch, Pairs
from studio.learn.trainer import Task, fit
from studio.sim.crop import align
from studio.sim.hand import Hand, load_hand


class InverseCNN(nn.Module):
    """``forward(crops (B, 1, S, S)) -> theta (B, 21)`` rad (unclipped); :meth:`predict` takes raw shadows."""

    kind = "inverse"  # checkpoint kind

    @classmethod
    def config_from_dict(cls, d: dict) -> InverseConfig:
        return InverseConfig(**(d | {"channels": tuple(d["channels"])}))

    def __init__(self, cfg: InverseConfig | None = None, hand: Hand | None = None):
        super().__init__()
        self.cfg = cfg or InverseConfig()
        self.hand = hand or load_hand()
        layers: list[nn.Module] = []
        c_in = 1
        for c in self.cfg.channels:
            layers += [nn.Conv2d(c_in, c, 3, stride=2, padding=1), nn.GroupNorm(min(8, c), c), nn.ReLU(inplace=True)]
            c_in = c
        self.convs = nn.Sequential(*layers)
        side = self.cfg.input_size // 2 ** len(self.cfg.channels)
        self.head = nn.Sequential(
            nn.Flatten(), nn.Linear(c_in * side * side, self.cfg.hidden), nn.ReLU(inplace=True),
            nn.Linear(self.cfg.hidden, self.hand.dof),
        )  # fmt: skip
        centre = (self.hand.lower + self.hand.upper) / 2
        self.register_buffer("centre", torch.tensor(centre, dtype=torch.float32))  # (21,) rad, mid-range

    def crops(self, shadows: torch.Tensor | np.ndarray) -> torch.Tensor:
        """Shadows ``(B, [1,] H, W)`` (1 = shadow, any side) → aligned network input ``(B, 1, S, S)``."""
        x = torch.as_tensor(shadows).float()
        return align(x, self.cfg.input_size, self.cfg.pad)[0][:, None]

    def forward(self, crops: torch.Tensor) -> torch.Tensor:
        return self.centre + self.head(self.convs(crops))

    @torch.no_grad()
    def predict(self, shadows: torch.Tensor | np.ndarray) -> np.ndarray:
        """Shadows ``(B, [1,] H, W)`` or one ``(H, W)`` → ``theta (B, 21)`` rad, clipped to the joint limits."""
        was = self.training
        self.eval()
        device = self.centre.device
        theta = self(self.crops(shadows).to(device)).double().cpu().numpy()
        self.train(was)
        return np.clip(theta, self.hand.lower, self.hand.upper)  # in float64: the limits exactly


def load_inverse(path: Path, hand: Hand | None = None, device: str = "cpu") -> tuple[InverseCNN, Checkpoint]:
    """Load an inverse CNN (eval mode, on ``device``) and its checkpoint; refuses another kind or hand."""
    return load_model(path, InverseCNN, hand, device)


@torch.no_grad()
def evaluate_mse(model: InverseCNN, batches: list[Batch]) -> float:
    """Mean squared joint error (rad², predictions clipped to the limits) over held-out batches."""
    total, n = 0.0, 0
    for theta, masks in batches:
        pred = torch.from_numpy(model.predict(masks)).float()
        total += ((pred - theta) ** 2).mean(dim=1).sum().item()
        n += len(theta)
    return total / max(n, 1)


def _mse(model: InverseCNN, theta: torch.Tensor, masks: torch.Tensor) -> torch.Tensor:
    return ((model(model.crops(masks).to(theta.device)) - theta) ** 2).mean()


def train_inverse(
    cfg: InverseTrainConfig,
    model_cfg: InverseConfig | None = None,
    hand: Hand | None = None,
    resume: bool = False,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> dict:
    """Train an inverse CNN (architecture ``model_cfg``, default ``InverseConfig()``) with MSE on (shadow, θ) pairs
    and checkpoint it to ``cfg.out``; returns its metrics (``test_mse``, ``val_mse``, ``initial_val_mse``... in rad²,
    clipped predictions; see :func:`studio.learn.trainer.fit`: its stages "train", "val", "test" and ``cancel``)."""
    hand = hand or load_hand()
    mcfg = model_cfg or InverseConfig()
    task = Task(
        build=lambda: InverseCNN(mcfg, hand),
        loss=_mse,
        evaluate=evaluate_mse,
        metric="mse",
        pairs=lambda: Pairs(cfg, hand, cfg.resolution, fit=False),
    )
    return fit(cfg, task, resume=resume, overwrite=overwrite, progress=progress, cancel=cancel)
