"""``shadow-studio evaluate`` (the paper's Table 1 over a folder of targets), ``shadow-studio evaluate-video`` (Table
2: the six video rows over sequences, :mod:`studio.evaluate.table2`) and ``shadow-studio train-inverse``.

``evaluate-video`` loads every sequence first (sampled frames, expressive masks, keyframes, once for all rows),
then runs the rows with the CPU preset (``--preset paper`` for the paper's GPU sizes; single budget flags override
either). Ctrl-C stops within a search or refinement step and still writes the table of the finished runs (exit
code 130)."""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
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


PRESETS = ("cpu", "paper")  # evaluate-video --preset: CPU_SEQUENCE (default) or PAPER_SEQUENCE (GPU sizes)


def add_sequence_flags(p: argparse.ArgumentParser) -> None:
    """``--preset cpu|paper`` and the sequence budgets (first/next search, refinement, candidates) over it."""
    from studio.imitate.sequence import CPU_SEQUENCE, SequenceConfig

    p.add_argument("--preset", choices=PRESETS, default="cpu",
                   help="budgets: cpu = CPU_SEQUENCE (minutes a sequence on 2 cores), paper = PAPER_SEQUENCE "
                        "(the paper's sizes, for a GPU); the flags below override single fields "
                        "(default: cpu)")  # fmt: skip
    for prefix, base in (("first-", CPU_SEQUENCE.first), ("next-", CPU_SEQUENCE.next)):
        add_config_flags(p, SearchConfig, ("batch", "iterations"), prefix=prefix, base=base,
                         base_name=f"CPU_SEQUENCE.{prefix[:-1]}", aliases={"iterations": "iters"})  # fmt: skip
    add_config_flags(p, RefineConfig, ("steps", "restarts"), prefix="refine-", base=CPU_SEQUENCE.refine,
                     base_name="CPU_SEQUENCE.refine")  # fmt: skip
    add_config_flags(p, SequenceConfig, ("candidates",), base=CPU_SEQUENCE, base_name="CPU_SEQUENCE")


def sequence_config_from_args(args: argparse.Namespace):
    """The preset with the budget flags that were given (a default shown in --help is the CPU preset's)."""
    from dataclasses import fields, replace

    from studio.cli.flags import dest_of, given
    from studio.imitate.sequence import CPU_SEQUENCE, PAPER_SEQUENCE

    def over(base, prefix: str = "", **extra):
        dests = {f.name: dest_of(prefix, f.name) for f in fields(base)}
        return replace(base, **{k: getattr(args, d) for k, d in dests.items() if given(args, d)} | extra)

    preset, seed = (PAPER_SEQUENCE if args.preset == "paper" else CPU_SEQUENCE), args.seed
    first, next_ = over(preset.first, "first-", seed=seed), over(preset.next, "next-", seed=seed)
    return over(preset, first=first, next=next_, refine=over(preset.refine, "refine-", seed=seed))


def _evaluate_video(args: argparse.Namespace) -> int:
    import torch

    threads = torch.get_num_threads()
    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        return _run_video_evaluation(args)
    finally:
        torch.set_num_threads(threads)


def _run_video_evaluation(args: argparse.Namespace) -> int:
    import sys
    import time

    import torch
    from tqdm import tqdm

    from studio.cli.imitate import ctrl_c_cancels
    from studio.evaluate.table2 import ROWS, VideoEvaluator, gather_sequences, json_rows, prepare_sequence, write_table
    from studio.imitate.clip_loss import clip_from_args
    from studio.imitate.keyframes import KeyframeConfig
    from studio.imitate.losses import LossConfig
    from studio.imitate.sequence import SequenceImitator
    from studio.imitate.still import DEFAULT_MODEL
    from studio.imitate.transitions import TransitionConfig
    from studio.imitate.video import VideoConfig
    from studio.learn.selfmodel import load_selfmodel

    t0 = time.perf_counter()
    sources = gather_sequences(args.sources)
    cfg = sequence_config_from_args(args)
    transition = config_from_args(args, TransitionConfig, prefix="transition-")
    model, _ = load_selfmodel(Path(args.model or DEFAULT_MODEL), device=args.device)
    video_cfg = config_from_args(args, VideoConfig, size=model.cfg.resolution)
    keyframe_cfg = config_from_args(args, KeyframeConfig)
    names = [p.name for p in sources]
    names = [n if names.count(n) == 1 else str(p) for n, p in zip(names, sources, strict=True)]
    sequences = []  # every sequence loads before the slow part
    for p, name in zip(tqdm(sources, desc="load", unit="sequence", disable=args.quiet), names, strict=True):
        sequences.append(prepare_sequence(p, video_cfg, keyframe_cfg, name))
    clip = clip_from_args(args, device=next(model.parameters()).device)
    loss_cfg = LossConfig(use_clip=clip is not None, crop_size=model.cfg.resolution)
    runs = tqdm(total=len(sequences) * len(ROWS), desc="evaluate-video", unit="run", disable=args.quiet)
    step_bar: list[tqdm] = []

    def progress(stage: str, step: int, total: int, best: float) -> None:
        if args.quiet:
            return
        if not step_bar or step_bar[0].desc != stage:
            if step_bar:
                step_bar.pop().close()
            step_bar.append(tqdm(total=total, desc=stage, unit="step", leave=False))
        step_bar[0].update(step - step_bar[0].n)
        step_bar[0].set_postfix(best=f"{best:.4f}", refresh=False)

    with SequenceImitator(model, cfg, loss_cfg=loss_cfg, clip=clip) as seq, ctrl_c_cancels() as cancel:
        result = VideoEvaluator(seq, cfg, transition).run(
            sequences, progress, lambda done, total, name: (runs.update(1), runs.set_postfix_str(name)), cancel
        )
    for bar in [*step_bar, runs]:
        bar.close()
    result.settings |= {"model": str(args.model or DEFAULT_MODEL), "preset": args.preset, "video": asdict(video_cfg),
                        "keyframes": asdict(keyframe_cfg), "threads": torch.get_num_threads()}  # fmt: skip
    paths = write_table(result, Path(args.out))
    if not args.quiet:
        print(Path(paths["markdown"]).read_text())
    summary = {"files": paths, "clip": loss_cfg.use_clip, "preset": args.preset, "cancelled": result.cancelled,
               "sequences": [s.name for s in sequences], "seconds": round(time.perf_counter() - t0, 1),
               "rows": json_rows(result.rows)}  # fmt: skip
    print(json.dumps(summary, allow_nan=False, default=str))
    if result.cancelled:
        print(f"shadow-studio evaluate-video: cancelled: wrote the finished runs to {args.out}", file=sys.stderr)
        return 130
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

    from studio.imitate.keyframes import KeyframeConfig
    from studio.imitate.transitions import TransitionConfig
    from studio.imitate.video import VideoConfig

    v = sub.add_parser("evaluate-video", help="Table 2: the six video rows (Independent/Sequential × Base/+Exp/"
                       "+Exp+Temp) on sequences, with transition success (Markdown + CSV)")  # fmt: skip
    v.add_argument("sources", nargs="+", help="video files, frame folders (PNG/JPEG masks or shadow footage) and/or "
                   "folders of them (each frame sub-folder or video file a sequence)")  # fmt: skip
    v.add_argument("--out", required=True, help="folder for table2.md, table2.csv, per_sequence.csv, settings.json")
    v.add_argument("--model", default=None, help="self-model checkpoint (default assets/models/selfmodel_cpu128.pt)")
    add_config_flags(v, VideoConfig, ("hz", "fps"))
    add_config_flags(v, KeyframeConfig, ("tau",))
    add_sequence_flags(v)
    add_config_flags(v, TransitionConfig, ("total",), prefix="transition-")
    v.add_argument("--seed", type=ranged(int, "[0, ∞)"), default=SearchConfig.seed, metavar="N",
                   help=f"seed of the searches and refinements (default: {SearchConfig.seed})")  # fmt: skip
    v.add_argument("--threads", type=ranged(int, "[0, ∞)"), default=1, metavar="N",
                   help="torch CPU threads (default: 1, fastest on shared cores; 0 = torch's default)")  # fmt: skip
    v.add_argument("--device", default=None, help="cpu or cuda, for the self-model and CLIP (default: cuda if present)")
    v.add_argument("--quiet", action="store_true", help="no progress bars and no table on stdout (JSON only)")
    add_clip_arguments(v)
    v.set_defaults(func=_evaluate_video)

    from studio.cli.train import add_trainer_flags
    from studio.learn.config import InverseConfig, InverseTrainConfig

    t = sub.add_parser("train-inverse", help="train the inverse-CNN baseline (shadow → joint angles, MSE)")
    add_config_flags(t, InverseTrainConfig, ("resolution",))
    add_config_flags(t, InverseConfig, ("input_size",))
    add_trainer_flags(t, InverseTrainConfig())
    t.set_defaults(func=_train_inverse)
