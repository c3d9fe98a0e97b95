"""The inverse-CNN baseline (DESIGN §4 "Baselines"): a shadow image → joint angles, trained with MSE.

The network sees the shadow the way the losses do: the bounding-box crop of its pixels, padded and made square
(:func:`studio.sim.crop.align`), so a target framed by :func:`studio.imitate.targets.load_target` and a
shadow in the rig's window look alike. ``crop (B, 1, S, S) → strided convs → FC → theta (B, 21) rad``; the output is the
joints' range centre plus a learnt offset, and predictions are clipped to the joint limits. Training pairs come
from the renderer (fresh every step) or from shards; checkpoints carry the config, the hand hash, the rig and metrics.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from studio.errors import StudioError
from studio.sim.crop import align
from studio.learn.train import lr_at
from studio.sim.hand import Hand, load_hand
from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer

log = logging.getLogger(__name__)
CHECKPOINT_KIND = "inverse-cnn"


class InverseCheckpointError(StudioError):
    """An inverse-CNN checkpoint is missing, unreadable, or made for another hand."""


@dataclass(frozen=True)
class InverseConfig:
    """Architecture of the inverse CNN."""

    input_size: int = 64  # side of the aligned shadow crop fed to the network, pixels (a multiple of 16)
    channels: tuple[int, ...] = (16, 32, 64, 128)  # conv widths; each stage halves the side (stride 2)
    hidden: int = 256  # width of the fully connected layer before the 21 outputs
    pad: float = 5.0  # crop padding, pixels of a 256-pixel image (as the losses' LossConfig.pad)

    def __post_init__(self) -> None:
        if self.input_size % (2 ** len(self.channels)):
            raise ValueError(f"input_size must be a multiple of {2 ** len(self.channels)}, got {self.input_size}")


@dataclass(frozen=True)
class InverseTrainConfig:
    """How ``shadow-studio train-inverse`` trains the inverse CNN (fields named as in ``studio.learn.train``)."""

    out: str = "runs/inverse.pt"  # checkpoint file written
    data: str | None = None  # shard folder from `collect` (train/val/test splits); None renders pairs on the fly
    resolution: int = 128  # rendered shadow side for on-the-fly pairs (the self-model's resolution)
    steps: int = 3000  # optimiser steps
    batch_size: int = 64  # pairs per step
    lr: float = 2e-3  # peak AdamW learning rate (warm-up + cosine schedule of studio.learn.train.lr_at)
    weight_decay: float = 1e-4  # AdamW weight decay
    warmup: int = 100  # linear warm-up steps
    eval_every: int = 500  # steps between validation passes
    eval_size: int = 1024  # on-the-fly validation/test set size (shards use their own splits)
    seed: int = 0  # data and initialisation seed
    threads: int | None = None  # torch CPU threads (None: torch default)


class InverseCNN(nn.Module):
    """``forward(crops (B, 1, S, S)) -> theta (B, 21)`` rad (unclipped); :meth:`predict` takes raw shadows."""

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


def save_inverse(path: Path, model: InverseCNN, rig: dict, metrics: dict, train_cfg: dict | None = None) -> None:
    """Atomic save of the weights with the config, the hand hash, the rig and the metrics."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    blob = {
        "format": 1,
        "kind": CHECKPOINT_KIND,
        "config": asdict(model.cfg),
        "hand_hash": model.hand.hash,
        "rig": rig,
        "metrics": metrics,
        "train": train_cfg or {},
        "state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()},
    }
    tmp = path.with_name(path.name + ".tmp")
    torch.save(blob, tmp)
    tmp.replace(path)


def load_inverse(path: Path, hand: Hand | None = None) -> tuple[InverseCNN, dict]:
    """Load an inverse CNN (eval mode, CPU) and its checkpoint info; refuses one made for another hand."""
    path, hand = Path(path), hand or load_hand()
    if not path.is_file():
        raise InverseCheckpointError(f"{path}: inverse-CNN checkpoint not found (make one with `shadow-studio "
                                     "train-inverse --out PATH`)")  # fmt: skip
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many types for corrupt files
        raise InverseCheckpointError(f"{path}: unreadable checkpoint ({e.__class__.__name__}: {e})") from None
    if not isinstance(blob, dict) or blob.get("kind") != CHECKPOINT_KIND or "state_dict" not in blob:
        raise InverseCheckpointError(f"{path}: not an inverse-CNN checkpoint (made by `shadow-studio train-inverse`)")
    if blob["hand_hash"] != hand.hash:
        raise InverseCheckpointError(
            f"{path}: trained for hand {blob['hand_hash']}, but the current hand is {hand.hash}; retrain it"
        )
    cfg = blob["config"]
    model = InverseCNN(InverseConfig(**(cfg | {"channels": tuple(cfg["channels"])})), hand)
    model.load_state_dict(blob["state_dict"])
    info = {k: blob.get(k, {}) for k in ("rig", "metrics", "train")}
    return model.eval(), info


class _Pairs:
    """``(theta (B, 21), shadows (B, 1, H, W))`` float batches for training and held-out sets."""

    def __init__(self, cfg: InverseTrainConfig, hand: Hand):
        self.cfg, self.hand = cfg, hand
        if cfg.data:
            from studio.learn.dataset import ShardStream
            from studio.learn.shards import list_shards, read_shard

            self.stream = lambda split, shuffle: ShardStream(Path(cfg.data), split, cfg.batch_size, shuffle, cfg.seed,
                                                             hand)  # fmt: skip
            self.rig = read_shard(list_shards(Path(cfg.data))[0], hand.hash).meta["rig"]
        else:
            self.renderer = ShadowRenderer(hand, Rig(resolution=cfg.resolution))
            self.rig = self.renderer.rig.to_dict()

    def _rendered(self, n: int, seed) -> tuple[torch.Tensor, torch.Tensor]:
        theta, _ = sample_poses(self.hand, n, np.random.default_rng(seed))
        masks = self.renderer.render(theta, check=False)
        return torch.from_numpy(theta.astype(np.float32)), torch.from_numpy(masks.astype(np.float32))[:, None]

    def train(self) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        step, stream = 0, self.stream("train", True) if self.cfg.data else None
        while True:
            if stream is not None:
                yield from stream  # one pass per epoch, reshuffled each time
            else:
                yield self._rendered(self.cfg.batch_size, [self.cfg.seed, step])
                step += 1

    def held_out(self, split: str) -> list[tuple[torch.Tensor, torch.Tensor]]:
        if self.cfg.data:
            return list(self.stream(split, False))
        theta, masks = self._rendered(self.cfg.eval_size, [self.cfg.seed, 10**9 + {"val": 1, "test": 2}[split]])
        return list(zip(theta.split(256), masks.split(256)))


@torch.no_grad()
def evaluate_mse(model: InverseCNN, batches: list) -> float:
    """Mean squared joint error (rad², predictions clipped to the limits) over held-out batches."""
    total, n = 0.0, 0
    for theta, masks in batches:
        pred = torch.from_numpy(model.predict(masks)).float()
        total += ((pred - theta) ** 2).mean(dim=1).sum().item()
        n += len(theta)
    return total / max(n, 1)


def train_inverse(
    cfg: InverseTrainConfig,
    model_cfg: InverseConfig | None = None,
    hand: Hand | None = None,
    progress: Callable[[int, int, dict], None] | None = None,
    cancel: threading.Event | None = None,
) -> dict:
    """Train an inverse CNN with MSE on (shadow, θ) pairs and save it to ``cfg.out``; returns its metrics.

    Metrics: ``val_mse``/``test_mse`` (rad², clipped predictions), ``initial_val_mse`` (before training),
    ``first_train_mse`` (first batch), ``train_mse`` (running mean of the last steps), ``steps``, ``seconds``.
    ``cancel`` stops early and saves.
    """
    hand = hand or load_hand()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    torch.manual_seed(cfg.seed)
    model = InverseCNN(model_cfg, hand)
    data = _Pairs(cfg, hand)
    val = data.held_out("val")
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    metrics: dict = {"initial_val_mse": evaluate_mse(model, val)}
    t0 = time.perf_counter()
    running, step, batches = None, 0, data.train()
    model.train()
    while step < cfg.steps and not (cancel is not None and cancel.is_set()):
        theta, masks = next(batches)
        for g in opt.param_groups:
            g["lr"] = lr_at(step, cfg)
        loss = ((model(model.crops(masks)) - theta) ** 2).mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        if running is None:
            running = metrics["first_train_mse"] = loss.item()
        running = 0.98 * running + 0.02 * loss.item()
        if step % cfg.eval_every == 0 or step == cfg.steps:
            metrics |= {"val_mse": evaluate_mse(model, val), "train_mse": running, "steps": step}
            model.train()
        if progress:
            progress(step, cfg.steps, {"loss": running, **{k: v for k, v in metrics.items() if k == "val_mse"}})
    metrics |= {"test_mse": evaluate_mse(model, data.held_out("test")), "steps": step,
                "seconds": round(time.perf_counter() - t0, 1), "samples_seen": step * cfg.batch_size}  # fmt: skip
    save_inverse(Path(cfg.out), model, data.rig, metrics, asdict(cfg))
    log.info("inverse CNN saved to %s (test MSE %.4f rad²)", cfg.out, metrics["test_mse"])
    return metrics
