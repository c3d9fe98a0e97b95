"""The shadow self-model S(θ): joint angles → analytic FK → neural decoder → shadow image (DESIGN §4).

``theta (B, 21) rad → T_world_child (B, 21, 4, 4) → flatten 336 → MLP → (C, 8, 8) → residual blocks →
log2(res / 8) transposed-conv upsamplings → sigmoid (B, 1, res, res)`` (probability of shadow).
``input="theta"`` is the paper's ablation: the same decoder fed the raw angles (as sin/cos) instead of FK.
Checkpoints are ``studio.learn.checkpoint``'s (kind ``"selfmodel"``); loading checks the kind and the hand.
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import nn

from studio.learn.checkpoint import Checkpoint, load_model
from studio.learn.config import SelfModelConfig
from studio.sim.hand import Hand, load_hand
from studio.sim.kinematics import TorchFK


class _ResBlock(nn.Module):
    def __init__(self, c: int):
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(c, c, 3, padding=1), nn.GroupNorm(8, c), nn.ReLU(inplace=True),
            nn.Conv2d(c, c, 3, padding=1), nn.GroupNorm(8, c),
        )  # fmt: skip

    def forward(self, x):
        return torch.relu(x + self.body(x))


class SelfModel(nn.Module):
    """``forward(theta (B, 21)) -> (B, 1, res, res)`` shadow probabilities; differentiable in θ."""

    kind = "selfmodel"  # checkpoint kind

    @classmethod
    def config_from_dict(cls, d: dict) -> SelfModelConfig:
        return SelfModelConfig(**d)

    def __init__(self, cfg: SelfModelConfig, hand: Hand | None = None):
        super().__init__()
        self.cfg = cfg
        self.hand = hand or load_hand()
        self.fk = TorchFK(self.hand, device="cpu")
        n_in = 21 * 16 if cfg.input == "fk" else 2 * self.hand.dof
        c = cfg.channels
        self.mlp = nn.Sequential(
            nn.Linear(n_in, cfg.hidden), nn.ReLU(inplace=True), nn.Linear(cfg.hidden, c * 64), nn.ReLU(inplace=True)
        )  # fmt: skip
        self.blocks = nn.Sequential(*[_ResBlock(c) for _ in range(cfg.res_blocks)])
        ups: list[nn.Module] = []
        for _ in range(cfg.upsamplings - 1):
            c_out = max(cfg.min_channels, c // 2)
            ups += [nn.ConvTranspose2d(c, c_out, 4, stride=2, padding=1), nn.GroupNorm(8, c_out), nn.ReLU(True)]
            c = c_out
        self.up = nn.Sequential(*ups)
        # the last transposed conv emits the image's logits directly (a full-resolution conv with few
        # channels is many times slower on CPU)
        self.head = nn.ConvTranspose2d(c, 1, 4, stride=2, padding=1)

    def _apply(self, fn, *args, **kwargs):
        """Keep the FK chain on the module's device and dtype (``.to``/``.cuda``/``.double``)."""
        out = super()._apply(fn, *args, **kwargs)
        p = next(self.parameters())
        if p.device != self.fk.device or p.dtype != self.fk.dtype:
            self.fk.chain = self.fk.chain.to(device=p.device, dtype=p.dtype)
            self.fk.device, self.fk.dtype = p.device, p.dtype
        return out

    def features(self, theta: torch.Tensor) -> torch.Tensor:
        """``theta (B, 21)`` → network input ``(B, 336)`` (FK) or ``(B, 42)`` (sin/cos ablation)."""
        if self.cfg.input == "theta":
            return torch.cat([torch.sin(theta), torch.cos(theta)], dim=1)
        T = self.fk.joint_frames(theta)  # (B, 21, 4, 4)
        scale = torch.ones(4, 4, dtype=T.dtype, device=T.device)
        scale[:3, 3] = self.cfg.translation_scale
        return (T * scale).flatten(1)

    def logits(self, theta: torch.Tensor) -> torch.Tensor:
        x = self.mlp(self.features(theta))
        x = x.view(-1, self.cfg.channels, 8, 8)
        return self.head(self.up(self.blocks(x)))

    def forward(self, theta: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.logits(theta))


def load_selfmodel(path: Path, hand: Hand | None = None, device: str | None = None) -> tuple[SelfModel, Checkpoint]:
    """Load a self-model checkpoint for ``hand`` (refuses another kind or hand); the model in eval mode on ``device``
    (None: CUDA when present) and its checkpoint (config, hand hash, rig, metrics, training config)."""
    return load_model(path, SelfModel, hand, device)
