"""``shadow-studio evaluate`` (the paper's Table 1 over a folder of targets), ``shadow-studio evaluate-video`` (Table
2: the six video rows over sequences, :mod:`studio.evaluate.table2`) and ``shadow-studio train-inverse``.

``evaluate-video`` loads every sequence first (sampled frames, expressive masks, keyframes, once for all rows),
then runs the rows with the studio preset (``--preset paper`` for the paper's sizes; single budget flags override
either). Ctrl-C stops within a search or refinement step and still writes the table of the finished runs (exit
code 130). ``--workers N`` (local processes) or ``--ray [ADDRESS]`` spread the targets, or Table 2's (sequence,
row) runs, over workers that each load their own models (:mod:`studio.evaluate.table1_task`,
:mod:`studio.evaluate.table2_task`): the same rows as in one process."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

from studio.assets import asset
from studio.cli.device_flags import add_device_flags
from studio.cli.flags import add_config_flags, config_from_args, ranged
from studio.cli.progress import add_quiet_flag, ctrl_c_cancels
from studio.cli.run_flags import add_budget_flags, sequence_from_args
from studio.cli.scale_flags import add_fanout_flags, fanout_from_args, models_from_args
from studio.cli.source_flags import add_source_flags, still_config_from_args
from studio.errors import count
from studio.imitate.config import still_configs
from studio.learn.threads import torch_threads
from studio.targets.image_sets import gather_targets

DEFAULT_INVERSE = asset("models/inverse_cpu128.pt", must_exist=False)


def _train_inverse(args: argparse.Namespace) -> int:
    from studio.cli.train import run_training
    from studio.learn.config import InverseConfig, InverseTrainConfig
    from studio.learn.inverse import train_inverse

    cfg = config_from_args(args, InverseTrainConfig)
    model_cfg = config_from_args(args, InverseConfig)
    return run_training(args, "train-inverse", cfg.steps, cfg.out, lambda **kw: train_inverse(cfg, model_cfg, **kw))


def _evaluate(args: argparse.Namespace) -> int:
    files = gather_targets(args.targets, args.per_folder, args.per_class)  # a bad path fails before torch loads
    from studio.evaluate.table1 import FILES

    _check_table_folder(args.out, FILES, [*args.targets, args.model, args.inverse])
    _check_nn_data(args.nn_data)
    with torch_threads(args.threads):
        return _run_evaluation(args, files)  # (the ones spread over workers set their own threads)


def _run_evaluation(args: argparse.Namespace, files: list[Path]) -> int:
    from studio.cli.clip_flags import clip_from_args
    from studio.evaluate.config import EvalConfig
    from studio.evaluate.table1 import Evaluator, write_table
    from studio.imitate.still import DEFAULT_MODEL, Imitator
    from studio.jobs import TqdmBars
    from studio.learn.selfmodel import load_selfmodel
    from studio.targets.images import load_target

    target_cfg = still_config_from_args(args)
    search, refine, config, sweep = still_configs(sequence_from_args(args))
    model, _ = load_selfmodel(Path(args.model or DEFAULT_MODEL), device=args.device)
    size = model.cfg.resolution
    score_side = args.score_resolution or size
    targets = [  # every file loads before the slow part (framed at the scoring side too when it is another)
        (str(f), load_target(f, size, target_cfg), *([load_target(f, score_side, target_cfg)] * (score_side != size)))
        for f in files
    ]
    eval_cfg = EvalConfig(seed=0 if args.seed is None else args.seed, score_resolution=args.score_resolution,
                          roll=args.roll)  # fmt: skip
    fanout = fanout_from_args(args)
    if fanout.workers > 1 or fanout.ray:  # every worker loads its own models (studio.evaluate.table1_task)
        from studio.evaluate.table1_task import Table1Task, evaluate_spread

        task = Table1Task(models_from_args(args), str(args.inverse), str(args.nn_data), eval_cfg, search, refine,
                          config, sweep)  # fmt: skip
        task.check()  # before the index is built and the workers start
        clip = clip_from_args(args)  # said once here; each worker finds the same weights
        with TqdmBars(disable=args.quiet) as bars, ctrl_c_cancels() as cancel:
            if config.retrieve:  # built once, spread, before the workers load it (not once per worker)
                with Imitator(model, config=config) as im:
                    im.retrieval_index(bars, cancel, fanout)
            result = evaluate_spread(task, targets, fanout, progress=bars, cancel=cancel)
    else:
        clip = clip_from_args(args, device=next(model.parameters()).device)  # CLIP sits with the self-model
        imitator = Imitator(model, clip=clip, search=search, refine=refine, config=config, sweep=sweep)
        with imitator, Evaluator(imitator, Path(args.inverse), Path(args.nn_data), eval_cfg) as evaluator:
            with TqdmBars(disable=args.quiet) as bars, ctrl_c_cancels() as cancel:
                result = evaluator.run(targets, progress=bars, cancel=cancel)
    paths = write_table(result, Path(args.out))
    if not args.quiet:
        print(Path(paths["markdown"]).read_text())
    summary = {"files": paths, "clip": getattr(clip, "name", None), "rows": result.rows,
               "cancelled": cancel.is_set()}  # as every verb says it  # fmt: skip
    print(json.dumps(summary, allow_nan=False, default=str))
    if cancel.is_set():
        done = len({r["target"] for r in result.records})
        print(f"shadow-studio evaluate: stopped by Ctrl-C; the table holds the {count(done, 'target')} finished",
              file=sys.stderr)  # fmt: skip
        return 130
    return 0


def _check_nn_data(folder: str) -> None:
    """Refuse a missing ``--nn-data`` before anything loads (every worker, or this process, would fail on it)."""
    from studio.errors import ShardError
    from studio.learn.shards import list_shards

    if not Path(folder).is_dir():
        raise ShardError(f"--nn-data {folder}: no such folder; the Random and Nearest Neighbour rows draw from it: "
                         f"make it with `shadow-studio collect --resolution 128 --n 50000 --out {folder}` (128: the "
                         "shipped self-model's side)")  # fmt: skip
    list_shards(Path(folder))


def _check_table_folder(out: str, files: tuple[str, ...], inputs: list) -> None:
    """Refuse a table folder whose files would overwrite an input or land inside a folder of targets."""
    from studio.targets.path_checks import check_outputs

    check_outputs([Path(out) / f for f in files], inputs=inputs, folders=[p for p in inputs if p and Path(p).is_dir()])


def _evaluate_video(args: argparse.Namespace) -> int:
    from studio.evaluate.table2 import FILES

    _check_table_folder(args.out, FILES, [*args.sources, args.model])
    with torch_threads(args.threads):
        return _run_video_evaluation(args)


def _run_video_evaluation(args: argparse.Namespace) -> int:
    import sys
    import time

    import torch

    from studio.cli.clip_flags import clip_from_args
    from studio.evaluate.sequences import gather_sequences, prepare_sequence
    from studio.evaluate.table2 import VideoEvaluator, json_rows, write_table
    from studio.imitate.config import LossConfig
    from studio.imitate.sequence import SequenceImitator
    from studio.imitate.still import DEFAULT_MODEL
    from studio.imitate.transitions import TransitionConfig
    from studio.learn.selfmodel import load_selfmodel
    from studio.targets.keyframes import KeyframeConfig
    from studio.targets.video import VideoConfig

    t0 = time.perf_counter()
    sources = gather_sequences(args.sources)
    from studio.errors import report
    from studio.jobs import TqdmBars

    cfg = sequence_from_args(args)
    transition = config_from_args(args, TransitionConfig, prefix="transition-")
    model, _ = load_selfmodel(Path(args.model or DEFAULT_MODEL), device=args.device)
    video_cfg = config_from_args(args, VideoConfig, size=model.cfg.resolution)
    keyframe_cfg = config_from_args(args, KeyframeConfig)
    names = [p.name for p in sources]
    names = [n if names.count(n) == 1 else str(p) for n, p in zip(names, sources, strict=True)]
    sequences = []  # every sequence loads before the slow part
    with TqdmBars(disable=args.quiet) as loaded:
        for i, (p, name) in enumerate(zip(sources, names, strict=True)):
            sequences.append(prepare_sequence(p, video_cfg, keyframe_cfg, name))
            report(loaded, "load", i + 1, len(sources), item=name)
    clip = clip_from_args(args, device=next(model.parameters()).device)
    loss_cfg = LossConfig(use_clip=clip is not None, crop_size=model.cfg.resolution)
    fanout = fanout_from_args(args)
    with (
        TqdmBars(disable=args.quiet) as bars,
        SequenceImitator(model, cfg, loss_cfg=loss_cfg, clip=clip) as seq,
        ctrl_c_cancels() as cancel,
    ):
        evaluator = VideoEvaluator(seq, cfg, transition)
        if fanout.workers > 1 or fanout.ray:  # every worker loads its own model (studio.evaluate.table2_task)
            from studio.evaluate.table2_task import Table2Task, evaluate_video_spread

            task = Table2Task(models_from_args(args), cfg, transition, evaluator.rows)
            seq.imitator.retrieval_index(bars, cancel, fanout)  # built once, spread, before the workers load it
            result = evaluate_video_spread(evaluator, task, sequences, fanout, bars, cancel)
        else:
            result = evaluator.run(sequences, bars, cancel)
    result.settings |= {"model": str(args.model or DEFAULT_MODEL), "preset": args.preset, "video": asdict(video_cfg),
                        "keyframes": asdict(keyframe_cfg), "threads": torch.get_num_threads()}  # fmt: skip
    paths = write_table(result, Path(args.out))
    if not args.quiet:
        print(Path(paths["markdown"]).read_text())
    summary = {"files": paths, "clip": getattr(clip, "name", None), "preset": args.preset,
               "cancelled": result.cancelled, "sequences": [s.name for s in sequences],
               "seconds": round(time.perf_counter() - t0, 1),
               "rows": json_rows(result.rows)}  # fmt: skip
    print(json.dumps(summary, allow_nan=False, default=str))
    if result.cancelled:
        print(f"shadow-studio evaluate-video: cancelled: wrote the finished runs to {args.out}", file=sys.stderr)
        return 130
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from studio.cli.clip_flags import add_clip_arguments
    from studio.evaluate.config import EvalConfig

    p = sub.add_parser("evaluate", help="Table 1: baselines and ours on a set of still targets (Markdown + CSV)")
    p.add_argument("targets", nargs="+", help="target image files and/or folders (sub-folders: see --per-folder)")
    p.add_argument("--out", required=True, help="folder for table1.md, table1.csv and per_target.csv")
    p.add_argument("--model", default=None, help="self-model checkpoint (default assets/models/selfmodel_cpu128.pt)")
    p.add_argument("--inverse", default=str(DEFAULT_INVERSE), help="inverse-CNN checkpoint (from train-inverse)")
    p.add_argument("--nn-data", default="data/sx128", help="training shards for Random and Nearest Neighbour")
    p.add_argument("--per-folder", type=ranged(int, "[1, 100000]"), default=None, metavar="N",
                   help="take the first N images of each sub-folder (default: all)")  # fmt: skip
    p.add_argument("--per-class", type=ranged(int, "[1, 100000]"), default=None, metavar="N",
                   help="then the first N images of each class (the name before its last '-': camel-1)")  # fmt: skip
    add_source_flags(p, video=False)
    add_budget_flags(p, video=False)
    add_config_flags(p, EvalConfig, ("score_resolution",))
    add_device_flags(p, zero_threads=True)
    add_quiet_flag(p, "no progress bar and no table on stdout (JSON only)")
    add_clip_arguments(p)
    add_fanout_flags(p)
    p.set_defaults(func=_evaluate)

    from studio.imitate.transitions import TransitionConfig
    from studio.targets.keyframes import KeyframeConfig
    from studio.targets.video import VideoConfig

    v = sub.add_parser("evaluate-video", help="Table 2: the six video rows (Independent/Sequential × Base/+Exp/"
                       "+Exp+Temp) on sequences, with transition success (Markdown + CSV)")  # fmt: skip
    v.add_argument("sources", nargs="+", help="video files, frame folders (PNG/JPEG masks or shadow footage) and/or "
                   "folders of them (each frame sub-folder or video file a sequence)")  # fmt: skip
    v.add_argument("--out", required=True, help="folder for table2.md, table2.csv, per_sequence.csv, settings.json")
    v.add_argument("--model", default=None, help="self-model checkpoint (default assets/models/selfmodel_cpu128.pt)")
    add_config_flags(v, VideoConfig, ("hz", "fps"))
    add_config_flags(v, KeyframeConfig, ("tau",))
    add_budget_flags(v, modes=False)
    add_config_flags(v, TransitionConfig, ("total",), prefix="transition-")
    add_device_flags(v, zero_threads=True)
    add_quiet_flag(v, "no progress bars and no table on stdout (JSON only)")
    add_clip_arguments(v)
    add_fanout_flags(v)
    v.set_defaults(func=_evaluate_video)

    from studio.cli.train import add_trainer_flags
    from studio.learn.config import InverseConfig, InverseTrainConfig

    t = sub.add_parser("train-inverse", help="train the inverse-CNN baseline (shadow → joint angles, MSE)")
    add_config_flags(t, InverseTrainConfig, ("resolution",))
    add_config_flags(t, InverseConfig, ("input_size",))
    add_trainer_flags(t, InverseTrainConfig())
    t.set_defaults(func=_train_inverse)
