"""``shadow-studio train``: train the shadow self-model (or its θ→image ablation) with a progress bar.

The flags are the fields of ``studio.learn.train.TrainConfig`` (the shared trainer's plus the architecture's): each
flag's default, help and range come from the config (``studio.cli.flags``). ``train-inverse``
(``studio.cli.evaluate``) shares :func:`add_trainer_flags` and :func:`run_training`.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable

from studio.cli.flags import add_config_flags
from studio.cli.scale_flags import add_fanout_flags, fanout_from_args

# the shared trainer's fields that are flags (``out`` and ``data`` are added with their verb's help)
TRAINER_FLAGS = ("steps", "batch_size", "lr", "weight_decay", "warmup", "eval_every", "eval_size", "seed",
                 "device", "threads", "rig_file")  # fmt: skip


def add_trainer_flags(p: argparse.ArgumentParser, base) -> None:
    """Add ``--out``, ``--data``/``--on-the-fly``, the trainer's flags (defaults from ``base``, a training config),
    ``--resume``, ``--force`` and ``--quiet``."""
    from studio.cli.device_flags import device_arg
    from studio.learn.config import TrainerConfig

    add_config_flags(p, TrainerConfig, ("out",), base=base)
    src = p.add_mutually_exclusive_group()
    add_config_flags(src, TrainerConfig, ("data",), base=base)
    src.add_argument("--on-the-fly", dest="data", action="store_const", const=None,
                     help="render fresh pairs every step (the default)")  # fmt: skip
    add_config_flags(p, TrainerConfig, TRAINER_FLAGS, base=base)
    for action in p._actions:  # --device is checked as it is read: cuda without a GPU is one line, at once
        if action.dest == "device":
            action.type = device_arg
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue training the checkpoint at --out")
    again.add_argument("--force", action="store_true", help="replace an existing checkpoint at --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def run_training(args: argparse.Namespace, desc: str, steps: int, out: str, train: Callable[..., dict]) -> int:
    """Run ``train(resume=, overwrite=, progress=, cancel=)`` under one progress bar named ``desc`` over ``steps``
    (the running training loss as its best, the last validation and test losses after it); print the JSON summary
    last. The first Ctrl-C sets ``cancel``: the trainer stops within the step and leaves a checkpoint that
    ``--resume`` continues exactly, the summary says ``"cancelled": true`` and the exit status is 130."""
    from studio.cli.progress import ctrl_c_cancels
    from studio.errors import Progress
    from studio.jobs import TqdmBars
    from studio.targets.path_checks import check_outputs

    check_outputs([out], inputs=[args.data])  # the checkpoint never replaces a shard it trains on
    with TqdmBars(disable=args.quiet, leave=True) as bars, ctrl_c_cancels() as cancel:
        held = {"loss": math.nan}  # the trainer's "val" and "test" stages go on the one bar, after the training loss

        def progress(p: Progress) -> None:
            if p.stage == "train":
                held["loss"] = p.best
            else:
                held[p.stage] = p.best
            item = ", ".join(f"{k} {v:.4f}" for k, v in held.items() if k != "loss")
            bars(Progress(desc, p.step, p.total, held["loss"], item))

        bars(Progress(desc, 0, steps))  # the bar shows while the data and the first batch load
        metrics = train(resume=args.resume, overwrite=args.force, progress=progress, cancel=cancel)
    print(json.dumps({"checkpoint": out, **metrics}))
    return 130 if metrics.get("cancelled") else 0


def _train(args: argparse.Namespace) -> int:
    from studio.cli.flags import config_from_args
    from studio.learn.config import TrainConfig
    from studio.learn.train import train

    cfg = config_from_args(args, TrainConfig)
    fanout = fanout_from_args(args)
    if not fanout.ray:
        if fanout.workers > 1:
            raise ValueError("training spreads over workers on Ray only: add --ray (a local Ray, or an address)")
        return run_training(args, "train", cfg.steps, cfg.out, lambda **kw: train(cfg, **kw))
    from functools import partial
    from pathlib import Path

    if cfg.batch_size % fanout.workers:  # before Ray starts (the trainer says it too)
        raise ValueError(f"the batch of {cfg.batch_size} does not split evenly over {fanout.workers} workers: "
                         "choose a batch size that is a multiple of the worker count")  # fmt: skip
    if Path(cfg.out).exists() and not (args.resume or args.force):
        raise ValueError(f"{cfg.out} exists: pass --resume to continue training it, --force to replace it, "
                         "or choose another --out")  # fmt: skip

    def on_ray(resume: bool, overwrite: bool, progress, cancel) -> dict:
        from studio.learn.ray_train import fit_on_ray

        run = partial(train, cfg, resume=resume, overwrite=overwrite)
        return fit_on_ray(run, cfg.out, "selfmodel", cfg.steps, fanout, progress, cancel)

    return run_training(args, "train", cfg.steps, cfg.out, on_ray)


def register(sub: argparse._SubParsersAction) -> None:
    from studio.learn.config import TrainConfig

    p = sub.add_parser("train", help="train the shadow self-model from shards or on-the-fly renders")
    add_config_flags(p, TrainConfig, ("model", "input", "resolution"))
    add_trainer_flags(p, TrainConfig())
    add_fanout_flags(p)
    p.set_defaults(func=_train)
