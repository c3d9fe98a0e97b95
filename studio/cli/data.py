"""``shadow-studio collect``: self-exploration data into resumable shards, with a progress bar."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from studio.cli.flags import add_config_flags, config_from_args
from studio.cli.progress import ctrl_c_cancels
from studio.cli.scale_flags import add_fanout_flags, fanout_from_args
from studio.learn.config import CollectConfig


def _collect(args: argparse.Namespace) -> int:
    from studio.jobs import TqdmBars
    from studio.learn.dataset import collect

    cfg = config_from_args(args, CollectConfig)
    fanout = fanout_from_args(args)
    t0 = time.perf_counter()
    with TqdmBars(disable=args.quiet, leave=True) as bars, ctrl_c_cancels() as cancel:
        summary = collect(Path(args.out), cfg, progress=bars, cancel=cancel, fanout=fanout)
    seconds = time.perf_counter() - t0
    if cancel.is_set():
        print(f"shadow-studio collect: stopped by Ctrl-C; {summary['samples']} samples in finished shards stay in "
              f"{args.out} (run the same command again to continue)", file=sys.stderr)  # fmt: skip
        return 130
    summary |= {"seconds": round(seconds, 2), "pairs_per_s": round(summary["samples"] / max(seconds, 1e-9), 1)}
    print(json.dumps(summary))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("collect", help="sample poses, render their shadows, write resumable shards")
    p.add_argument("--out", default="data/selfexplore", help="dataset folder (default data/selfexplore)")
    add_config_flags(p, CollectConfig, ("n", "shard_size", "seed", "resolution", "window", "rig_file"))
    add_fanout_flags(p)
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_collect)
