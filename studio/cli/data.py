"""``shadow-studio collect``: self-exploration data into resumable shards, with a progress bar."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path


def _collect(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from studio.learn.dataset import CollectConfig, collect

    cfg = CollectConfig(
        n=args.n, shard_size=args.shard_size, seed=args.seed, resolution=args.resolution, window=args.window
    )
    t0 = time.perf_counter()
    with tqdm(total=cfg.n, unit="pair", desc="collect", disable=args.quiet) as bar:

        def progress(done: int, total: int) -> None:
            bar.update(done - bar.n)

        summary = collect(Path(args.out), cfg, progress=progress)
    seconds = time.perf_counter() - t0
    summary |= {"seconds": round(seconds, 2), "pairs_per_s": round(summary["samples"] / max(seconds, 1e-9), 1)}
    print(json.dumps(summary))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("collect", help="sample poses, render their shadows, write resumable shards")
    p.add_argument("--n", type=int, default=20000, help="number of pose/shadow pairs (default 20000)")
    p.add_argument("--out", default="data/selfexplore", help="dataset folder (default data/selfexplore)")
    p.add_argument("--shard-size", type=int, default=5000, help="pairs per shard file (default 5000)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--resolution", type=int, default=256, help="shadow image side in pixels (default 256)")
    p.add_argument("--window", type=float, default=0.6, help="backdrop window side in metres (default 0.6)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_collect)
