"""``shadow-studio train``: train the shadow self-model (or its θ→image ablation) with a progress bar."""

from __future__ import annotations

import argparse
import json


def _train(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from studio.learn.train import TrainConfig, train

    cfg = TrainConfig(
        out=args.out, data=args.data, model=args.model, input=args.input, resolution=args.resolution,
        steps=args.steps, batch_size=args.batch_size, lr=args.lr, eval_every=args.eval_every, seed=args.seed,
        device=args.device, threads=args.threads,
    )  # fmt: skip
    with tqdm(total=cfg.steps, unit="step", desc="train", disable=args.quiet) as bar:

        def progress(step: int, total: int, stats: dict) -> None:
            bar.update(step - bar.n)
            bar.set_postfix({k: f"{v:.4f}" for k, v in stats.items() if v is not None}, refresh=False)

        metrics = train(cfg, resume=args.resume, progress=progress)
    print(json.dumps({"checkpoint": cfg.out, **metrics}))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("train", help="train the shadow self-model from shards or on-the-fly renders")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--data", default=None, help="shard folder made by `collect` (0.7/0.2/0.1 split)")
    src.add_argument("--on-the-fly", action="store_true", help="render fresh pairs every step (default)")
    p.add_argument("--out", default="runs/selfmodel.pt", help="checkpoint file (default runs/selfmodel.pt)")
    p.add_argument("--model", choices=("cpu", "paper"), default="cpu", help="cpu: 128², small; paper: 256²")
    p.add_argument("--input", choices=("fk", "theta"), default="fk", help="fk (paper) or theta (ablation)")
    p.add_argument("--resolution", type=int, default=None, help="override the output resolution")
    p.add_argument("--steps", type=int, default=6000, help="optimiser steps (default 6000)")
    p.add_argument("--batch-size", type=int, default=64, help="pairs per step (default 64)")
    p.add_argument("--lr", type=float, default=2e-3, help="peak learning rate (default 2e-3)")
    p.add_argument("--eval-every", type=int, default=500, help="steps between validation + checkpoint")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default=None, help="cpu or cuda (default: cuda when present)")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument("--resume", action="store_true", help="continue training the checkpoint at --out")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_train)
