"""``shadow-studio collect``: self-exploration data into resumable shards, with a progress bar."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from studio.cli.flags import add_config_flags, config_from_args
from studio.learn.config import CollectConfig


def _collect(args: argparse.Namespace) -> int:
    from studio.jobs import TqdmBars
    from studio.learn.dataset import collect

    cfg = config_from_args(args, CollectConfig)
    t0 = time.perf_counter()
    with TqdmBars(disable=args.quiet, leave=True) as bars:
        summary = collect(Path(args.out), cfg, progress=bars)
    seconds = time.perf_counter() - t0
    summary |= {"seconds": round(seconds, 2), "pairs_per_s": round(summary["samples"] / max(seconds, 1e-9), 1)}
    print(json.dumps(summary))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("collect", help="sample poses, render their shadows, write resumable shards")
    p.add_argument("--out", default="data/selfexplore", help="dataset folder (default data/selfexplore)")
    add_config_flags(p, CollectConfig, ("n", "shard_size", "seed", "resolution", "window", "rig_file"))
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_collect)
