"""Training the self-model with MAE on (pose, shadow) pairs: from shards (0.7/0.2/0.1 split) or rendered on the
fly (fresh pairs every step; fixed held-out validation and test sets). AdamW with warm-up + cosine decay,
periodic validation, atomic checkpoints that resume exactly, CUDA when present.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from studio.errors import StudioError
from studio.learn.selfmodel import CPU_CONFIG, PAPER_CONFIG, Checkpoint, SelfModel, read_checkpoint, save_checkpoint
from studio.sim.hand import Hand, load_hand
from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainConfig:
    """How ``shadow-studio train`` trains a self-model."""

    out: str = "runs/selfmodel.pt"  # checkpoint file written (and resumed from)
    data: str | None = None  # shard folder from `collect`; None renders pairs on the fly
    model: str = "cpu"  # architecture preset: "cpu" (128², small) or "paper" (256²)
    input: str = "fk"  # "fk" (the paper's model) or "theta" (the ablation)
    resolution: int | None = None  # override the preset's output resolution
    steps: int = 6000  # optimiser steps
    batch_size: int = 64  # pairs per step
    lr: float = 2e-3  # peak AdamW learning rate
    weight_decay: float = 1e-4  # AdamW weight decay
    warmup: int = 200  # linear warm-up steps before cosine decay to lr/50
    eval_every: int = 500  # steps between validation + checkpoint
    eval_size: int = 2048  # on-the-fly validation/test set size (shards use their own splits)
    seed: int = 0  # data and initialisation seed
    device: str | None = None  # "cpu", "cuda"; None picks CUDA when present
    threads: int | None = None  # torch CPU threads (None: torch default)

    def model_config(self):
        base = CPU_CONFIG if self.model == "cpu" else PAPER_CONFIG if self.model == "paper" else None
        if base is None:
            raise ValueError(f"model must be 'cpu' or 'paper', got {self.model!r}")
        return replace(base, input=self.input, resolution=self.resolution or base.resolution)


def lr_at(step: int, cfg: TrainConfig) -> float:
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    t = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
    return cfg.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(1.0, t))))


def _fit(masks: torch.Tensor, res: int) -> torch.Tensor:
    """Area-downsample ``(B, 1, R, R)`` masks to ``res`` when R is a multiple of it."""
    R = masks.shape[-1]
    if R == res:
        return masks
    if R % res:
        raise StudioError(f"shards are {R}² but the model is {res}²: collect at {res} or a multiple of it")
    return F.avg_pool2d(masks, R // res)


class _Data:
    """Train batches, validation and test sets, from shards or the renderer."""

    def __init__(self, cfg: TrainConfig, hand: Hand, res: int):
        self.cfg, self.hand, self.res = cfg, hand, res
        if cfg.data:
            from studio.learn.dataset import ShardStream

            self.stream = lambda split, shuffle: ShardStream(Path(cfg.data), split, cfg.batch_size, shuffle, cfg.seed,
                                                             hand)  # fmt: skip
            self.rig = self._shard_rig()
        else:
            self.renderer = ShadowRenderer(hand, Rig(resolution=res))
            self.rig = self.renderer.rig.to_dict()

    def _shard_rig(self) -> dict:
        from studio.learn.shards import list_shards, read_shard

        meta = read_shard(list_shards(Path(self.cfg.data))[0], self.hand.hash).meta
        _fit(torch.zeros(1, 1, meta["resolution"], meta["resolution"]), self.res)
        return meta["rig"] | {"resolution": self.res}

    def train_batches(self, start_step: int) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        if self.cfg.data:
            while True:
                for theta, masks in self.stream("train", True):
                    yield theta, _fit(masks, self.res)
        step = start_step
        while True:  # batch k is drawn from seed (seed, k): resuming continues the same stream
            theta, _ = sample_poses(self.hand, self.cfg.batch_size, np.random.default_rng([self.cfg.seed, step]))
            masks = self.renderer.render(theta, check=False)
            yield torch.from_numpy(theta.astype(np.float32)), torch.from_numpy(masks.astype(np.float32))[:, None]
            step += 1

    def held_out(self, split: str) -> list[tuple[torch.Tensor, torch.Tensor]]:
        if self.cfg.data:
            return [(t, _fit(m, self.res)) for t, m in self.stream(split, False)]
        tag = {"val": 1, "test": 2}[split]
        theta, _ = sample_poses(self.hand, self.cfg.eval_size, np.random.default_rng([self.cfg.seed, 10**9 + tag]))
        masks = self.renderer.render(theta, check=False)
        t = torch.from_numpy(theta.astype(np.float32))
        m = torch.from_numpy(masks.astype(np.float32))[:, None]
        return list(zip(t.split(256), m.split(256)))


@torch.no_grad()
def evaluate_mae(model: SelfModel, batches: list, device) -> float:
    """Mean absolute error over held-out batches (pixel mean, then sample mean)."""
    was = model.training
    model.eval()
    total, n = 0.0, 0
    for theta, masks in batches:
        pred = model(theta.to(device))
        total += (pred - masks.to(device)).abs().mean(dim=(1, 2, 3)).sum().item()
        n += len(theta)
    model.train(was)
    return total / max(n, 1)


def train(
    cfg: TrainConfig,
    hand: Hand | None = None,
    resume: bool = False,
    progress: Callable[[int, int, dict], None] | None = None,
    cancel: threading.Event | None = None,
) -> dict:
    """Train (or resume) a self-model; returns the metrics written into the checkpoint."""
    hand = hand or load_hand()
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    device = torch.device(cfg.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    mcfg = cfg.model_config()
    out = Path(cfg.out)
    if out.exists() and not resume:
        raise StudioError(f"{out} exists: pass --resume to continue training it, or choose another --out")
    torch.manual_seed(cfg.seed)
    model = SelfModel(mcfg, hand).to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    step, metrics, elapsed = 0, {}, 0.0
    if resume and out.exists():
        blob = read_checkpoint(out)
        if blob["config"] != asdict(mcfg) or blob["hand_hash"] != hand.hash:
            raise StudioError(f"{out}: its architecture or hand differs from these options; use another --out")
        model.load_state_dict(blob["state_dict"])
        extra = blob.get("extra", {})
        if "optimizer" in extra:
            opt.load_state_dict(extra["optimizer"])
        step, metrics = int(extra.get("step", 0)), blob.get("metrics", {})
        elapsed = float(extra.get("elapsed_s", 0.0))
        log.info("resuming %s at step %d", out, step)
    data = _Data(cfg, hand, mcfg.resolution)
    val = data.held_out("val")

    def checkpoint(final: bool = False) -> None:
        info = Checkpoint(mcfg, hand.hash, data.rig, metrics, {"config": asdict(cfg)})
        extra = None if final else {"optimizer": opt.state_dict(), "step": step, "elapsed_s": elapsed}
        save_checkpoint(out, model, info, extra if not final else {"step": step, "elapsed_s": elapsed})

    model.train()
    batches = data.train_batches(step)
    t0 = time.perf_counter() - elapsed
    running = None
    while step < cfg.steps:
        if cancel is not None and cancel.is_set():
            break
        theta, masks = next(batches)
        for g in opt.param_groups:
            g["lr"] = lr_at(step, cfg)
        loss = (model(theta.to(device)) - masks.to(device)).abs().mean()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        step += 1
        running = loss.item() if running is None else 0.98 * running + 0.02 * loss.item()
        if step % cfg.eval_every == 0 or step == cfg.steps:
            metrics |= {"val_mae": evaluate_mae(model, val, device), "steps": step, "train_mae": running}
            elapsed = time.perf_counter() - t0
            checkpoint()
        if progress:
            progress(step, cfg.steps, {"loss": running, **{k: v for k, v in metrics.items() if k == "val_mae"}})
    elapsed = time.perf_counter() - t0
    if step >= cfg.steps:
        metrics |= {"test_mae": evaluate_mae(model, data.held_out("test"), device), "steps": step,
                    "seconds": round(elapsed, 1), "samples_seen": step * cfg.batch_size}  # fmt: skip
        checkpoint(final=True)
    else:
        checkpoint()
    return metrics
