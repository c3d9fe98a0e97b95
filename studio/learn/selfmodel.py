"""The shadow self-model S(θ): joint angles → analytic FK → neural decoder → shadow image (DESIGN §4).

``theta (B, 21) rad → T_world_child (B, 21, 4, 4) → flatten 336 → MLP → (C, 8, 8) → residual blocks →
log2(res / 8) transposed-conv upsamplings → sigmoid (B, 1, res, res)`` (probability of shadow).
``input="theta"`` is the paper's ablation: the same decoder fed the raw angles (as sin/cos) instead of FK.
Checkpoints carry the config, the hand hash, the rig and metrics; loading checks the hand.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import nn

from studio.errors import StudioError
from studio.sim.hand import Hand, load_hand
from studio.sim.kinematics import TorchFK


class CheckpointError(StudioError):
    """A self-model checkpoint is missing, unreadable, or made for another hand."""


@dataclass(frozen=True)
class SelfModelConfig:
    """Architecture of the self-model."""

    resolution: int = 256  # output image side (a power of two ≥ 16); paper 256, CPU configuration 128
    input: str = "fk"  # "fk": FK joint frames (336 numbers); "theta": the ablation, sin/cos of the raw angles
    hidden: int = 1024  # width of the MLP's hidden layer
    channels: int = 128  # feature channels at 8×8 (paper 128); halved at each upsampling, at least min_channels
    min_channels: int = 16  # narrowest decoder stage
    res_blocks: int = 2  # residual blocks at 8×8
    translation_scale: float = 10.0  # FK positions (metres) are multiplied by this before the MLP

    def __post_init__(self) -> None:
        n = math.log2(self.resolution / 8)
        if self.resolution < 16 or n != int(n):
            raise ValueError(f"resolution must be 8·2^k ≥ 16 (16, 32, 64, 128, 256...), got {self.resolution}")
        if self.input not in ("fk", "theta"):
            raise ValueError(f"input must be 'fk' or 'theta', got {self.input!r}")

    @property
    def upsamplings(self) -> int:
        return int(math.log2(self.resolution / 8))


CPU_CONFIG = SelfModelConfig(resolution=128, hidden=512, channels=64, min_channels=16)  # shipped small model
PAPER_CONFIG = SelfModelConfig()  # 256², 128 channels


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


@dataclass
class Checkpoint:
    """What a checkpoint file holds besides the weights."""

    config: SelfModelConfig  # architecture
    hand_hash: str  # hand the model was trained for
    rig: dict  # rig geometry (window, light, backdrop) of the training shadows
    metrics: dict = field(default_factory=dict)  # e.g. {"test_mae": ..., "val_mae": ..., "steps": ...}
    train: dict = field(default_factory=dict)  # training config and resume state summary


def save_checkpoint(path: Path, model: SelfModel, info: Checkpoint, extra: dict | None = None) -> None:
    """Atomic save of weights + info (+ optimiser state etc. in ``extra`` for resuming)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    blob = {
        "format": 1,
        "config": asdict(info.config),
        "hand_hash": info.hand_hash,
        "rig": info.rig,
        "metrics": info.metrics,
        "train": info.train,
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
    }
    if extra:
        blob["extra"] = extra
    tmp = path.with_name(path.name + ".tmp")
    torch.save(blob, tmp)
    tmp.replace(path)


def read_checkpoint(path: Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: self-model checkpoint not found (train one with `shadow-studio train`)")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for corrupt files
        raise CheckpointError(f"{path}: unreadable checkpoint ({e.__class__.__name__}: {e})") from None
    if not isinstance(blob, dict) or blob.get("format") != 1 or "state_dict" not in blob:
        raise CheckpointError(f"{path}: not a shadow-studio self-model checkpoint")
    return blob


def load_selfmodel(path: Path, hand: Hand | None = None, device: str | None = None) -> tuple[SelfModel, Checkpoint]:
    """Load a checkpoint for ``hand`` (refuses one trained for another hand); returns the model in eval mode."""
    hand = hand or load_hand()
    blob = read_checkpoint(path)
    if blob["hand_hash"] != hand.hash:
        raise CheckpointError(
            f"{path}: trained for hand {blob['hand_hash']}, but the current hand is {hand.hash}; retrain it"
        )
    cfg = SelfModelConfig(**blob["config"])
    model = SelfModel(cfg, hand)
    model.load_state_dict(blob["state_dict"])
    dev = device or ("cuda" if torch.cuda.is_available() else "cpu")
    model.to(dev).eval()
    info = Checkpoint(cfg, blob["hand_hash"], blob["rig"], blob.get("metrics", {}), blob.get("train", {}))
    return model, info
