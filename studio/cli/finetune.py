"""``shadow-studio finetune``: adapt a self-model to the real rig from photographed shadows (a capture set).

The flags are the fields of ``studio.learn.finetune.FinetuneConfig`` (the shared trainer's plus the capture set, the
starting model and the held-out share), each flag's default, help and range from the config (``studio.cli.flags``).
It runs under the same progress bar as ``train`` (:func:`studio.cli.train.run_training`) and prints, last, one JSON
line: ``checkpoint``, ``mae_sim_only``, ``mae_finetuned``, ``pairs_train``, ``pairs_held_out``, ``steps``,
``seconds``. The first Ctrl-C stops within a step, leaving a checkpoint that ``--resume`` continues (exit code 130).
"""

from __future__ import annotations

import argparse

from studio.cli.flags import add_config_flags

# FinetuneConfig's own flags (weight_decay and device are the shared trainer's, with its help)
FLAGS = ("captures", "model", "out", "steps", "batch_size", "lr", "warmup", "eval_every", "held_out_fraction",
         "held_out", "seed", "threads")  # fmt: skip


def _finetune(args: argparse.Namespace) -> int:
    from studio.cli.flags import config_from_args
    from studio.cli.train import run_training
    from studio.learn.finetune import FinetuneConfig, finetune
    from studio.targets.path_checks import check_outputs

    cfg = config_from_args(args, FinetuneConfig)
    inputs = [cfg.captures, cfg.start_model(), *([cfg.held_out] if cfg.held_out else [])]
    check_outputs([cfg.out], inputs=inputs)  # never replaces the model it starts from
    args.data = cfg.captures  # what run_training checks the output against too
    return run_training(args, "finetune", cfg.steps, cfg.out, lambda **kw: finetune(cfg, **kw))


def register(sub: argparse._SubParsersAction) -> None:
    from studio.cli.device_flags import device_arg
    from studio.learn.config import TrainerConfig
    from studio.learn.finetune import FinetuneConfig

    p = sub.add_parser("finetune", help="fine-tune a self-model on photographed shadows of the real rig")
    add_config_flags(p, FinetuneConfig, FLAGS)
    add_config_flags(p, TrainerConfig, ("weight_decay", "device"), base=FinetuneConfig())
    for action in p._actions:  # --device is checked as it is read, as train's
        if action.dest == "device":
            action.type = device_arg
    again = p.add_mutually_exclusive_group()
    again.add_argument("--resume", action="store_true", help="continue fine-tuning the checkpoint at --out")
    again.add_argument("--force", action="store_true", help="replace an existing checkpoint at --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_finetune)
