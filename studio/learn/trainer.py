"""The one trainer of every network (the self-model and the inverse CNN), DESIGN §5.12.

AdamW with a linear warm-up and a cosine decay to lr/50 (:func:`lr_at`), batches of ``(theta (B, 21) rad,
shadows (B, 1, R, R))`` pairs from shards (0.7/0.2/0.1 split) or rendered on the fly (batch ``k`` drawn from the seed
``(seed, k)``, fixed held-out validation and test sets), validation and an atomic, resumable checkpoint
(``studio.learn.checkpoint``) every ``eval_every`` steps, CUDA when present. Long runs report
:class:`~studio.errors.Progress` (stages "train", "val", "test": step of the total steps, the loss as best) and stop
within a step when ``cancel`` is set (DESIGN §5.11), leaving a checkpoint that ``resume`` continues exactly.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import torch
from torch import nn

from studio.errors import ProgressFn, StudioError, report, stopped
from studio.learn.checkpoint import CheckpointError, read_checkpoint, same_config, save_model
from studio.learn.config import TrainerConfig
from studio.learn.pairs import Batch, BatchesAhead, Pairs
from studio.learn.threads import set_torch_threads

log = logging.getLogger(__name__)


def lr_at(step: int, cfg: TrainerConfig) -> float:
    """Learning rate of optimiser step ``step`` (0-based): linear warm-up, then cosine from lr to lr/50."""
    if step < cfg.warmup:
        return cfg.lr * (step + 1) / cfg.warmup
    t = (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup)
    return cfg.lr * (0.02 + 0.98 * 0.5 * (1 + math.cos(math.pi * min(1.0, t))))


@dataclass(frozen=True)
class Replica:
    """This process's place in a data-parallel run (``torch.distributed`` already set up, e.g. by Ray Train's
    workers, :mod:`studio.learn.ray_train`); the default is a run of one. Replica ``rank`` of ``world`` trains on
    rows ``rank::world`` of every global batch; DDP averages the gradients, so with equal parts each step is the
    single process's step on the whole batch (up to float summation order)."""

    rank: int = 0
    world: int = 1

    @property
    def main(self) -> bool:
        """The replica that validates, tests, checkpoints and reports."""
        return self.rank == 0

    def mean(self, value: float) -> float:
        """``value`` averaged over the replicas (the batch's loss: each replica's rows weigh the same)."""
        return value if self.world == 1 else self._sum(value) / self.world

    def any(self, flag: bool) -> bool:
        """Whether any replica says so (a stop: all stop at the same step)."""
        return flag if self.world == 1 else self._sum(float(flag)) > 0

    @staticmethod
    def _sum(value: float) -> float:
        import torch.distributed as dist

        t = torch.tensor([value], dtype=torch.float64)
        dist.all_reduce(t)
        return float(t[0])


@dataclass
class Task:
    """What the trainer trains: how to build the network, its loss, its held-out metric and its data."""

    build: Callable[[], nn.Module]  # makes the network (after seeding; a fine-tune loads its start): .kind, .cfg, .hand
    loss: Callable[[nn.Module, torch.Tensor, torch.Tensor], torch.Tensor]  # (model, theta, shadows) on its device
    evaluate: Callable[[nn.Module, list[Batch]], float]  # held-out metric over batches (lower is better)
    metric: str  # the metric's name in the results: "mae" → val_mae, test_mae, train_mae...
    pairs: Callable[[], Pairs]  # makes the data source (anything with .rig, .train_batches(step), .held_out(split))
    record: dict = field(default_factory=dict)  # kept in the checkpoint's extra (a fine-tune's capture set)


def fit(
    cfg: TrainerConfig,
    task: Task,
    resume: bool = False,
    overwrite: bool = False,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
    replica: Replica | None = None,
) -> dict:
    """Train ``task``'s network as ``cfg`` says and checkpoint it to ``cfg.out``; returns its metrics.

    ``replica``: this process's part of a data-parallel run (:class:`Replica`); only the main replica validates,
    tests, checkpoints, reports progress and returns metrics (the others return ``{}``), and a cancel seen by any
    replica stops them all at the same step.

    Reports stage "train" after every step (step of ``cfg.steps``, the running training loss as best), "val" after
    every validation (the validation metric) and "test" once at the end (the test metric). ``cancel`` stops within a
    step, with a resumable checkpoint of where it stopped.

    An existing ``cfg.out`` is continued with ``resume`` (same architecture and hand, else ``CheckpointError``),
    replaced with ``overwrite``, and otherwise refused. Metrics (with ``m = task.metric``): ``initial_val_m``
    (before training), ``first_train_m`` (first batch), ``train_m`` (running mean), ``val_m``, ``test_m``,
    ``steps``, ``seconds``, ``samples_seen``; plus ``cancelled: True`` when ``cancel`` stopped the run.
    """
    out, m = Path(cfg.out), task.metric
    if out.exists() and not (resume or overwrite):
        raise StudioError(f"{out} exists: pass --resume to continue training it, --force to replace it, "
                          "or choose another --out")  # fmt: skip
    if cfg.threads:
        set_torch_threads(cfg.threads)
    device = torch.device(cfg.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    rep = replica or Replica()
    if cfg.batch_size % rep.world:
        raise StudioError(f"the batch of {cfg.batch_size} does not split evenly over {rep.world} workers: "
                          "choose a batch size that is a multiple of the worker count")  # fmt: skip
    torch.manual_seed(cfg.seed)
    model = task.build().to(device)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    step, metrics, elapsed = 0, {}, 0.0
    if resume and out.exists():
        ckpt = read_checkpoint(out, model.kind, model.hand.hash)
        if not same_config(ckpt.config, asdict(model.cfg)):
            raise CheckpointError(f"{out}: trained with another architecture than these options; "
                                  "use its options or another --out")  # fmt: skip
        model.load_state_dict(ckpt.state_dict)
        if "optimizer" in ckpt.extra:
            opt.load_state_dict(ckpt.extra["optimizer"])
        step, metrics = int(ckpt.extra.get("step", 0)), dict(ckpt.metrics)
        elapsed = float(ckpt.extra.get("elapsed_s", 0.0))
        log.info("resuming %s at step %d", out, step)
    data = task.pairs()
    val = data.held_out("val") if rep.main else []
    if step == 0 and rep.main:
        metrics[f"initial_val_{m}"] = task.evaluate(model, val)
    net = model
    if rep.world > 1:  # gradients averaged over the replicas (the process group is the caller's)
        from torch.nn.parallel import DistributedDataParallel

        net = DistributedDataParallel(model, device_ids=[device.index] if device.type == "cuda" else None)
    if not rep.main:
        progress = None

    def checkpoint(resumable: bool) -> None:
        if not rep.main:
            return
        extra = task.record | {"step": step, "elapsed_s": elapsed}
        extra |= {"optimizer": opt.state_dict()} if resumable else {}
        save_model(out, model, data.rig, metrics, asdict(cfg), extra)

    model.train()
    batches = BatchesAhead(
        data.train_batches(step, (rep.rank, rep.world)) if rep.world > 1 else data.train_batches(step)
    )
    t0 = time.perf_counter() - elapsed
    running = metrics.get(f"train_{m}")
    stop = stopped(cancel)
    try:
        while step < cfg.steps and not stop:
            theta, masks = next(batches)
            for g in opt.param_groups:
                g["lr"] = lr_at(step, cfg)
            loss = task.loss(net, theta.to(device), masks.to(device).float())  # uint8 on the fly: cast here
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            value = rep.mean(loss.item())
            if running is None:
                running = metrics[f"first_train_{m}"] = value
            running = 0.98 * running + 0.02 * value
            report(progress, "train", step, cfg.steps, running)
            if step % cfg.eval_every == 0 or step == cfg.steps:
                metrics |= {f"train_{m}": running, "steps": step}
                if rep.main:
                    metrics[f"val_{m}"] = task.evaluate(model, val)
                    report(progress, "val", step, cfg.steps, metrics[f"val_{m}"])
                model.train()
                elapsed = time.perf_counter() - t0
                if step < cfg.steps:
                    checkpoint(resumable=True)
            stop = rep.any(stopped(cancel))
    finally:
        batches.close()
    elapsed = time.perf_counter() - t0
    if not rep.main:
        return {}
    if step < cfg.steps:  # cancelled: a resumable checkpoint of where it stopped
        metrics |= {f"train_{m}": running, "steps": step} if running is not None else {"steps": step}
        checkpoint(resumable=True)
        return metrics | {"cancelled": True}
    metrics |= {f"test_{m}": task.evaluate(model, data.held_out("test")), "steps": step,
                "seconds": round(elapsed, 1), "samples_seen": step * cfg.batch_size}  # fmt: skip
    report(progress, "test", step, cfg.steps, metrics[f"test_{m}"])
    checkpoint(resumable=False)
    log.info("%s saved to %s (test %s %.5f)", model.kind, out, m, metrics[f"test_{m}"])
    return metrics
