"""Spreading work on Ray against local processes: ``collect`` and ``evaluate`` (Table 1) on this machine.

Each job runs three ways in the same run: in this process (the reference path), on ``--workers`` spawned local
processes, and on ``--workers`` Ray actors of a local Ray (started before the timing, as a cluster would be running
already; its start-up is reported apart). It checks that every way gives identical results (the same shard bytes;
the same Table 1 records, seconds aside) and prints the ratios ``ray / processes`` (the goal: ≤ 1.3) and
``processes / one process``. The collect job's shards are the training images of Table 1's Random and Nearest
Neighbour baselines; Table 1 runs on ``--targets`` ASL letters (the shared ones, else the bundled stills) with the
CPU preset and the shipped models.

    python benchmarks/bench_ray.py [--pairs 40000] [--targets 8] [--workers 2]

JSON last: ``collect`` and ``evaluate`` each with ``seconds`` per way, ``ray_over_processes``,
``processes_over_local`` and ``identical``; ``ray_start_s``.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED_ASL = ROOT.parent / "shared" / "targets" / "asl"


def _ways(workers: int) -> dict:
    from studio.learn.fanout import FanoutConfig

    return {"local": FanoutConfig(), "processes": FanoutConfig(workers=workers),
            "ray": FanoutConfig(workers=workers, ray="local")}  # fmt: skip


def bench_collect(root: Path, pairs: int, workers: int) -> dict:
    from studio.learn.config import CollectConfig
    from studio.learn.dataset import collect
    from studio.learn.shards import list_shards

    cfg = CollectConfig(n=pairs, shard_size=2000, resolution=128)
    out, made = {}, {}
    for name, how in _ways(workers).items():
        t0 = time.perf_counter()
        collect(root / f"collect-{name}", cfg, fanout=how)
        out[name] = round(time.perf_counter() - t0, 2)
        made[name] = [p.read_bytes() for p in list_shards(root / f"collect-{name}")]
        print(f"collect {pairs} pairs at 128², {how.where}: {out[name]} s", flush=True)
    return _summary(out, made["local"] == made["processes"] == made["ray"])


def bench_evaluate(root: Path, n_targets: int, workers: int) -> dict:
    from studio.assets import asset

    from studio.evaluate.config import EvalConfig
    from studio.evaluate.table1_task import Table1Task, evaluate_spread
    from studio.evaluate.worker_models import ModelRecipe
    from studio.imitate.config import PRESETS, still_configs
    from studio.imitate.index_cache import cached_index
    from studio.imitate.still import DEFAULT_MODEL, Imitator
    from studio.targets.image_sets import gather_targets
    from studio.targets.images import load_target

    folder = SHARED_ASL if SHARED_ASL.is_dir() else asset("targets")
    files = [f for f in gather_targets([folder]) if f.suffix.lower() in (".jpeg", ".jpg", ".png")][:n_targets]
    targets = [(f.name, load_target(f, 128)) for f in files]
    search, refine, config, sweep = still_configs(PRESETS["studio"])
    with Imitator(config=config) as im:
        cached_index(im.renderer, im.retrieval_cfg)  # once per machine: every worker loads it
    models = ModelRecipe(str(DEFAULT_MODEL), device="cpu", use_clip=False)
    task = Table1Task(models, str(asset("models/inverse_cpu128.pt")), str(root / "collect-local"), EvalConfig(roll=0),
                      search, refine, config, sweep)  # fmt: skip
    out, records = {}, {}
    for name, how in _ways(workers).items():
        t0 = time.perf_counter()
        result = evaluate_spread(task, targets, how)
        out[name] = round(time.perf_counter() - t0, 2)
        records[name] = [{k: v for k, v in r.items() if k != "seconds"} for r in result.records]
        print(f"Table 1 on {len(targets)} targets, {how.where}: {out[name]} s", flush=True)
    same = json.dumps(records["local"]) == json.dumps(records["processes"]) == json.dumps(records["ray"])
    return _summary(out, same) | {"targets": len(targets)}


def _summary(seconds: dict, identical: bool) -> dict:
    return {"seconds": seconds, "identical": identical,
            "ray_over_processes": round(seconds["ray"] / seconds["processes"], 3),
            "processes_over_local": round(seconds["processes"] / seconds["local"], 3)}  # fmt: skip


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--pairs", type=int, default=40000, help="pairs collected (default 40000, 20 shards)")
    p.add_argument("--targets", type=int, default=8, help="Table 1 targets (default 8)")
    p.add_argument("--workers", type=int, default=2, help="local processes and Ray actors (default 2)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    import ray

    t0 = time.perf_counter()
    ray.init(num_cpus=args.workers, include_dashboard=False, log_to_driver=False, configure_logging=False)
    ray_start = round(time.perf_counter() - t0, 2)
    print(f"local Ray with {args.workers} CPUs started in {ray_start} s", flush=True)
    root = Path(tempfile.mkdtemp(prefix="bench_ray-"))
    try:
        out = {"collect": bench_collect(root, args.pairs, args.workers),
               "evaluate": bench_evaluate(root, args.targets, args.workers),
               "ray_start_s": ray_start, "workers": args.workers, "goal_ray_over_processes": 1.3}  # fmt: skip
    finally:
        ray.shutdown()
        shutil.rmtree(root, ignore_errors=True)
    return out


if __name__ == "__main__":
    result = main()
    print(json.dumps(result))
    sys.exit(0 if result["collect"]["identical"] and result["evaluate"]["identical"] else 1)
