"""``shadow-studio evaluate`` (the paper's Table 1 over a folder of targets) and ``shadow-studio train-inverse``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from studio.assets import asset
from studio.cli.flags import add_config_flags, config_from_args, ranged
from studio.cli.imitate import add_target_flags, target_config_from_args
from studio.imitate.refine import RefineConfig
from studio.imitate.search import CPU_SEARCH, SearchConfig

DEFAULT_INVERSE = asset("models/inverse_cpu128.pt", must_exist=False)


def _train_inverse(args: argparse.Namespace) -> int:
    from studio.cli.train import run_training
    from studio.learn.config import InverseConfig, InverseTrainConfig
    from studio.learn.inverse import train_inverse

    cfg = config_from_args(args, InverseTrainConfig)
    model_cfg = config_from_args(args, InverseConfig)
    return run_training(args, "train-inverse", cfg.steps, cfg.out, lambda **kw: train_inverse(cfg, model_cfg, **kw))


def _evaluate(args: argparse.Namespace) -> int:
    import torch

    threads = torch.get_num_threads()
    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        return _run_evaluation(args)
    finally:
        torch.set_num_threads(threads)


def _run_evaluation(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from studio.evaluate.table1 import EvalConfig, Evaluator, gather_targets, write_table
    from studio.imitate.clip_loss import clip_from_args
    from studio.imitate.still import DEFAULT_MODEL, Imitator
    from studio.imitate.targets import load_target
    from studio.learn.selfmodel import load_selfmodel

    files = gather_targets(args.targets, args.per_folder)
    target_cfg = target_config_from_args(args)
    search = config_from_args(args, SearchConfig, prefix="search-", base=CPU_SEARCH, seed=args.seed)
    refine = config_from_args(args, RefineConfig, prefix="refine-", seed=args.seed)
    model, _ = load_selfmodel(Path(args.model or DEFAULT_MODEL), device=args.device)
    size = model.cfg.resolution
    targets = [(str(f), load_target(f, size, target_cfg)) for f in files]  # every file loads before the slow part
    clip = clip_from_args(args, device=next(model.parameters()).device)  # CLIP sits with the self-model
    imitator = Imitator(model, clip=clip, search=search, refine=refine)
    with imitator, Evaluator(imitator, Path(args.inverse), Path(args.nn_data), EvalConfig(seed=args.seed)) as evaluator:
        with tqdm(total=len(targets), unit="target", desc="evaluate", disable=args.quiet) as bar:
            result = evaluator.run(
                targets, progress=lambda done, total, name: (bar.update(1), bar.set_postfix_str(name))
            )
    paths = write_table(result, Path(args.out))
    if not args.quiet:
        print(Path(paths["markdown"]).read_text())
    summary = {"files": paths, "clip": imitator.loss_cfg.use_clip, "rows": result.rows}
    print(json.dumps(summary, allow_nan=False, default=str))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from studio.imitate.clip_loss import add_clip_arguments

    p = sub.add_parser("evaluate", help="Table 1: baselines and ours on a set of still targets (Markdown + CSV)")
    p.add_argument("targets", nargs="+", help="target image files and/or folders (sub-folders: see --per-folder)")
    p.add_argument("--out", required=True, help="folder for table1.md, table1.csv and per_target.csv")
    p.add_argument("--model", default=None, help="self-model checkpoint (default assets/models/selfmodel_cpu128.pt)")
    p.add_argument("--inverse", default=str(DEFAULT_INVERSE), help="inverse-CNN checkpoint (from train-inverse)")
    p.add_argument("--nn-data", default="data/sx128", help="training shards for Random and Nearest Neighbour")
    p.add_argument("--per-folder", type=ranged(int, "[1, ∞)"), default=None, metavar="N",
                   help="take the first N images of each sub-folder (default: all)")  # fmt: skip
    add_target_flags(p)
    add_config_flags(p, SearchConfig, ("batch", "iterations"), prefix="search-", base=CPU_SEARCH,
                     base_name="CPU_SEARCH", aliases={"iterations": "iters"})  # fmt: skip
    add_config_flags(p, RefineConfig, ("steps", "restarts"), prefix="refine-")
    p.add_argument(
        "--seed",
        type=ranged(int, "[0, ∞)"),
        default=SearchConfig.seed,
        metavar="N",
        help=f"seed of the search, refinement and Random baseline (default: {SearchConfig.seed})",
    )
    p.add_argument("--threads", type=ranged(int, "[0, ∞)"), default=1, metavar="N",
                   help="torch CPU threads (default: 1, fastest on shared cores; 0 = torch's default)")  # fmt: skip
    p.add_argument("--device", default=None, help="cpu or cuda, for the self-model and CLIP (default: cuda if present)")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no table on stdout (JSON only)")
    add_clip_arguments(p)
    p.set_defaults(func=_evaluate)

    from studio.cli.train import add_trainer_flags
    from studio.learn.config import InverseConfig, InverseTrainConfig

    t = sub.add_parser("train-inverse", help="train the inverse-CNN baseline (shadow → joint angles, MSE)")
    add_config_flags(t, InverseTrainConfig, ("resolution",))
    add_config_flags(t, InverseConfig, ("input_size",))
    add_trainer_flags(t, InverseTrainConfig())
    t.set_defaults(func=_train_inverse)
