"""Learning from real shadows: fine-tune a self-model checkpoint on a capture set (``studio.learn.captures``).

The real rig differs from the nominal one (light distance, a small unintended mount roll, a thicker foam shell, the
hand off centre), so a self-model trained only in simulation mispredicts its shadows. :func:`finetune` starts from a
checkpoint's weights and trains them further through the one trainer (``studio.learn.trainer.fit``) on the capture
set's training split, resized to the model's side when the photographs' differ; the held-out split is the trainer's
"val" and "test" sets. The result is a checkpoint of the one format whose ``rig`` is the captures' (at the model's
resolution) and whose ``extra["captures"]`` names the set it learnt from (folder, count, sha256, split); its metrics
hold ``mae_sim_only`` (the starting model on the held-out captures) and ``mae_finetuned`` (after).

Torch is imported only when fine-tuning runs: the command line builds its flags from :class:`FinetuneConfig`
without it.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from studio.errors import ProgressFn
from studio.learn.captures import CaptureSet, CapturesMismatch, load_captures, split
from studio.learn.config import TrainerConfig

if TYPE_CHECKING:
    import torch

    from studio.sim.hand import Hand

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FinetuneConfig(TrainerConfig):
    """How ``shadow-studio finetune`` adapts a self-model to real shadows (sized for ≤ 2,000 pairs on a 2-core CPU:
    about a minute per 400 steps)."""

    out: str = "runs/selfmodel_finetuned.pt"  # fine-tuned checkpoint written (and resumed from)
    captures: str = "captures"  # capture set folder (captures.json + captures.npz)
    model: str | None = None  # starting self-model checkpoint; unset: the shipped 128² model
    steps: int = 400  # optimiser steps (400 × 32 pairs: ~7 passes over 1,800 pairs) [1, 10000000]
    batch_size: int = 32  # pairs per step [1, 1024]
    lr: float = 1e-3  # peak AdamW learning rate (the shipped model was trained at 2e-3) (0, 10]
    warmup: int = 40  # linear warm-up steps before the cosine decay to lr/50 [0, 10000000]
    eval_every: int = 100  # steps between held-out evaluations + checkpoints [1, 10000000]
    held_out_fraction: float = 0.1  # share of the captures held out for the before/after MAE (0, 1)
    held_out: str | None = None  # a second capture set held out whole (another session or walk); unset: a share
    seed: int = 0  # held-out split and batch order seed [0, 4294967295]
    threads: int | None = 1  # torch CPU threads (1 is fastest on shared cores) [1, 256]

    def __post_init__(self) -> None:
        super().__post_init__()
        if not 0 < self.held_out_fraction < 1:
            raise ValueError(f"held_out_fraction must be in (0, 1), got {self.held_out_fraction}")
        if self.data is not None:
            raise ValueError("fine-tuning reads a capture set (captures), not self-exploration shards (data)")

    def start_model(self) -> Path:
        """The starting checkpoint: ``model``, or the shipped self-model."""
        from studio.assets import asset

        return Path(self.model) if self.model else asset("models/selfmodel_cpu128.pt", must_exist=False)


def resize(masks: torch.Tensor, resolution: int) -> torch.Tensor:
    """``(B, 1, R, R)`` masks → ``(B, 1, resolution, resolution)`` by area (the share of each pixel in shadow)."""
    import torch.nn.functional as F

    if masks.shape[-1] == resolution:
        return masks
    return F.interpolate(masks, size=(resolution, resolution), mode="area")


class CapturePairs:
    """The trainer's data source (as ``studio.learn.pairs.Pairs``) over a capture set's two splits.

    ``train_batches``: batch ``k`` is ``batch_size`` distinct training pairs drawn from ``(seed, k)`` (a resumed run
    continues the same stream); ``held_out("val")`` and ``held_out("test")``: the held-out pairs, both. Masks become
    ``(B, 1, resolution, resolution)`` float32 in the unrolled hand's frame (DESIGN §1: turned by ``-roll`` when the
    captures' rig records a mount roll, then resized by area when the captures' side differs); ``rig`` is the
    captures' rig as the model sees it (no roll, the model's side)."""

    def __init__(self, train: CaptureSet, held_out: CaptureSet, resolution: int, batch_size: int, seed: int):
        self.train, self.held, self.res = train, held_out, resolution
        self.batch_size, self.seed = min(batch_size, len(train)), seed
        self.roll = float(train.rig.get("roll", 0.0))
        self.rig = {k: v for k, v in train.rig.items() if k != "roll"} | {"resolution": resolution}

    def _batch(self, cs: CaptureSet, rows: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
        import torch

        from studio.sim.roll import turn

        masks = turn(cs.masks[rows].astype(np.float32), -self.roll)
        return torch.from_numpy(cs.theta[rows]), resize(torch.from_numpy(masks)[:, None], self.res)

    def train_batches(self, start_step: int = 0, part: tuple[int, int] = (0, 1)):
        """Endless ``(theta (B, 21), masks (B, 1, res, res))`` training batches from step ``start_step``; ``part
        (r, W)``: rows ``r::W`` of each (a data-parallel replica's share)."""
        step = start_step
        while True:
            rng = np.random.default_rng([self.seed, step])
            rows = np.sort(rng.choice(len(self.train), self.batch_size, replace=False))
            yield self._batch(self.train, rows[part[0] :: part[1]])
            step += 1

    def held_out(self, split: str) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The held-out pairs as batches of up to 256 (``split`` "val" or "test": the same pairs)."""
        if split not in ("val", "test"):
            raise ValueError(f"split must be 'val' or 'test', got {split!r}")
        n = len(self.held)
        return [self._batch(self.held, np.arange(i, min(n, i + 256))) for i in range(0, n, 256)]


def _check_fit(cs: CaptureSet, model_rig: dict, where: str) -> None:
    """The captures must show the model's window (the model draws nothing outside it)."""
    if not math.isclose(cs.window, float(model_rig.get("window", cs.window)), rel_tol=1e-9):
        raise CapturesMismatch(f"{where}: captures show a {cs.window} m window but the model draws "
                               f"{model_rig['window']} m; rectify the photographs into the model's window")  # fmt: skip


def finetune(
    cfg: FinetuneConfig,
    hand: Hand | None = None,
    resume: bool = False,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> dict:
    """Fine-tune ``cfg.start_model()`` on the capture set ``cfg.captures`` and checkpoint it to ``cfg.out``.

    Returns ``{"checkpoint", "mae_sim_only", "mae_finetuned", "pairs_train", "pairs_held_out", "steps",
    "seconds"}`` (MAE over the held-out captures before and after; ``seconds`` of the whole call), plus
    ``"cancelled": True`` when ``cancel`` stopped it (``mae_finetuned`` is then None and ``resume`` continues it).
    Progress: the trainer's stages "train", "val", "test" (:func:`studio.learn.trainer.fit`). ``resume`` and
    ``overwrite`` as there; resuming with another capture set than the checkpoint's raises ``CapturesMismatch``.
    """
    from studio.learn.checkpoint import read_checkpoint, save_checkpoint
    from studio.learn.selfmodel import SelfModel, load_selfmodel
    from studio.learn.train import evaluate_mae
    from studio.learn.trainer import Task, fit
    from studio.sim.hand import load_hand

    t0 = time.perf_counter()
    hand = hand or load_hand()
    start = cfg.start_model()
    _, start_ckpt = load_selfmodel(start, hand, device="cpu")  # fails early: missing, another kind or hand
    captures = load_captures(cfg.captures, hand.hash)
    _check_fit(captures, start_ckpt.rig, cfg.captures)
    if cfg.held_out:  # a set of its own: no neighbour of a training pair sits in it (captures along a walk do)
        train, held = captures, load_captures(cfg.held_out, hand.hash)
        _check_fit(held, start_ckpt.rig, cfg.held_out)
        if held.rig != captures.rig:
            raise CapturesMismatch(f"{cfg.held_out} was rectified into another rig than {cfg.captures}")
    else:
        train, held = split(captures, cfg.held_out_fraction, cfg.seed)
    record = {"folder": str(Path(cfg.captures).resolve()), "count": len(captures), "sha256": captures.sha256,
              "source": captures.source, "pairs_train": len(train), "pairs_held_out": len(held),
              "start_model": str(start), "start_metrics": start_ckpt.metrics}  # fmt: skip
    if resume and Path(cfg.out).exists():
        done = read_checkpoint(cfg.out, SelfModel.kind, hand.hash).extra.get("captures", {})
        if done.get("sha256") != captures.sha256:
            raise CapturesMismatch(f"{cfg.out} was fine-tuned on another capture set ({done.get('folder')}); "
                                   "resume with that set, or use --force to start again")  # fmt: skip
    res = int(start_ckpt.config["resolution"])
    task = Task(
        build=lambda: load_selfmodel(start, hand, device="cpu")[0],
        loss=lambda model, theta, masks: (model(theta) - masks).abs().mean(),
        evaluate=evaluate_mae,
        metric="mae",
        pairs=lambda: CapturePairs(train, held, res, cfg.batch_size, cfg.seed),
        record={"captures": record},
    )
    log.info("fine-tuning %s on %d captures (%d held out) from %s", start, len(train), len(held), cfg.captures)
    metrics = fit(cfg, task, resume=resume, overwrite=overwrite, progress=progress, cancel=cancel)
    result = {"checkpoint": cfg.out, "mae_sim_only": metrics.get("initial_val_mae"),
              "mae_finetuned": metrics.get("test_mae"), "pairs_train": len(train), "pairs_held_out": len(held),
              "steps": metrics.get("steps", 0)}  # fmt: skip
    if metrics.get("cancelled"):
        return result | {"seconds": round(time.perf_counter() - t0, 1), "cancelled": True}
    ckpt = read_checkpoint(cfg.out, SelfModel.kind, hand.hash)
    ckpt.metrics |= {"mae_sim_only": result["mae_sim_only"], "mae_finetuned": result["mae_finetuned"]}
    save_checkpoint(cfg.out, ckpt)
    log.info("held-out MAE %.5f → %.5f", result["mae_sim_only"], result["mae_finetuned"])
    return result | {"seconds": round(time.perf_counter() - t0, 1)}
