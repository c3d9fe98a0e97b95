"""``shadow-studio evaluate`` (the paper's Table 1 over a folder of targets) and ``shadow-studio train-inverse``."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from studio.assets import asset

DEFAULT_INVERSE = asset("models/inverse_cpu128.pt", must_exist=False)


def _train_inverse(args: argparse.Namespace) -> int:
    from studio.cli.flags import config_from_args
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
    from studio.imitate.refine import RefineConfig
    from studio.imitate.search import CPU_SEARCH, SearchConfig
    from studio.imitate.still import DEFAULT_MODEL, Imitator

    files = gather_targets(args.targets, args.per_folder)
    search = SearchConfig(
        batch=args.search_batch or CPU_SEARCH.batch, iterations=args.search_iters or CPU_SEARCH.iterations,
        lr=CPU_SEARCH.lr, seed=args.seed,
    )  # fmt: skip
    refine = RefineConfig(steps=args.refine_steps, restarts=args.refine_restarts, seed=args.seed)
    clip = clip_from_args(args)
    imitator = Imitator(model_path=Path(args.model or DEFAULT_MODEL), clip=clip, search=search, refine=refine)
    targets = [(str(f), imitator.load(f)) for f in files]  # every file loads before the slow part starts
    evaluator = Evaluator(imitator, Path(args.inverse), Path(args.nn_data), EvalConfig(seed=args.seed))
    with tqdm(total=len(targets), unit="target", desc="evaluate", disable=args.quiet) as bar:
        result = evaluator.run(targets, progress=lambda done, total, name: (bar.update(1), bar.set_postfix_str(name)))
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
    p.add_argument("--per-folder", type=int, default=None, help="take the first N images of each sub-folder")
    p.add_argument("--search-batch", type=int, default=None, help="gradient-search batch (default: CPU preset)")
    p.add_argument("--search-iters", type=int, default=None, help="gradient-search iterations (default: CPU preset)")
    p.add_argument("--refine-steps", type=int, default=1000, help="hill-climbing steps per restart (paper 1000)")
    p.add_argument("--refine-restarts", type=int, default=8, help="hill-climbing restarts (paper 8)")
    p.add_argument("--seed", type=int, default=0, help="seed of the search, refinement and Random baseline")
    p.add_argument(
        "--threads",
        type=int,
        default=1,
        help="torch CPU threads (default 1: fastest on shared cores; 0 = torch's default)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar and no table on stdout (JSON only)")
    add_clip_arguments(p)
    p.set_defaults(func=_evaluate)

    from studio.cli.flags import add_config_flags
    from studio.cli.train import add_trainer_flags
    from studio.learn.config import InverseConfig, InverseTrainConfig

    t = sub.add_parser("train-inverse", help="train the inverse-CNN baseline (shadow → joint angles, MSE)")
    add_config_flags(t, InverseTrainConfig, ("resolution",))
    add_config_flags(t, InverseConfig, ("input_size",))
    add_trainer_flags(t, InverseTrainConfig())
    t.set_defaults(func=_train_inverse)
