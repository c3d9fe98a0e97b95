"""The self-model trained through Ray Train against one plain process: pairs per second and the test MAE.

Two runs of the one trainer (``studio.learn.train.train``), pairs rendered on the fly, in the same run of this
script: the reference, ``--ref-steps`` steps in this process with no Ray; then ``train --ray``'s path
(``studio.learn.ray_train.fit_on_ray``: Ray Train's ``TorchTrainer``, ``--workers`` workers with DDP, a local Ray)
for enough steps of ``--batch`` to see ``--pairs`` pairs, or as many as ``--budget-s`` seconds hold at the
reference's speed. It prints the Ray run's validation MAE as it goes, writes every figure to ``OUT/figures.json``
as soon as it is known (a run stopped at a time limit keeps them) and prints the JSON last: ``test_mae`` beside the
paper's 0.00643, ``pairs_per_s`` of both runs and ``ray_over_reference``.

    python benchmarks/bench_train_ray.py --model paper --pairs 2000000 --budget-s 330 \\
        --workers 1 --gpus-per-worker 1 --cpus-per-worker 12       # a GPU machine
    python benchmarks/bench_train_ray.py --model cpu --resolution 32 --batch 32 --pairs 6400 --ref-steps 20  # here
"""

from __future__ import annotations

import argparse
import functools
import json
import logging
import math
import os
import platform
import shutil
import sys
import time
from dataclasses import replace
from pathlib import Path

PAPER_TEST_MAE = 0.00643  # the paper's 256² self-model after 9,249,784 pairs


class _Clock:
    """Progress events with their times: pairs per second over the training steps after the first ``skip``, the
    intervals holding a validation and checkpoint left out."""

    def __init__(self, batch: int, skip: int, echo: bool, sink) -> None:
        self.batch, self.skip, self.echo, self.sink = batch, skip, echo, sink
        self.t_prev, self.validated = None, False
        self.steps, self.seconds = 0, 0.0
        self.val: list[tuple[int, float]] = []

    def __call__(self, p) -> None:
        now = time.perf_counter()
        if p.stage == "train":
            if self.t_prev is not None and p.step > self.skip and not self.validated:
                self.steps, self.seconds = self.steps + 1, self.seconds + now - self.t_prev
            self.t_prev, self.validated = now, False
        elif p.stage == "val":
            self.validated = True
            self.val.append((p.step, round(p.best, 6)))
            if self.echo:
                print(f"  step {p.step}/{p.total}: val MAE {p.best:.5f}, {self.pairs_per_s():,.0f} pairs/s",
                      flush=True)  # fmt: skip
            self.sink()

    def pairs_per_s(self) -> float:
        return self.steps * self.batch / self.seconds if self.seconds > 0 else math.nan


def _device() -> str:
    import torch

    return torch.cuda.get_device_name(0) if torch.cuda.is_available() else f"CPU ({os.cpu_count()} cores)"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="paper", help="architecture preset: paper (256²) or cpu (128²)")
    ap.add_argument("--resolution", type=int, default=None, help="output side instead of the preset's")
    ap.add_argument("--batch", type=int, default=256, help="global batch, pairs per step")
    ap.add_argument("--lr", type=float, default=2e-3, help="peak learning rate")
    ap.add_argument("--pairs", type=int, default=2_000_000, help="pairs the Ray run should see")
    ap.add_argument(
        "--budget-s", type=float, default=0.0, help="cap the Ray run's steps to this many seconds (0: none)"
    )
    ap.add_argument("--ref-steps", type=int, default=100, help="steps of the one-process reference")
    ap.add_argument("--eval-size", type=int, default=4096, help="validation and test poses")
    ap.add_argument("--evals", type=int, default=8, help="validations during the Ray run")
    ap.add_argument("--workers", type=int, default=1, help="Ray Train workers")
    ap.add_argument("--gpus-per-worker", type=float, default=None, help="default: 1 with CUDA, else 0")
    ap.add_argument("--cpus-per-worker", type=float, default=1.0, help="CPUs each worker reserves (renders its rows)")
    ap.add_argument("--out", default="runs/bench_train_ray", help="folder for the checkpoints and figures.json")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)

    import torch

    from studio.learn.config import TrainConfig
    from studio.learn.fanout import FanoutConfig
    from studio.learn.ray_train import fit_on_ray
    from studio.learn.train import train

    out = Path(args.out)
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    gpus = args.gpus_per_worker if args.gpus_per_worker is not None else float(torch.cuda.is_available())
    base = TrainConfig(model=args.model, resolution=args.resolution, batch_size=args.batch, lr=args.lr,
                       eval_size=args.eval_size, warmup=200)  # fmt: skip
    figures: dict = {"device": _device(), "host": platform.node(), "model": args.model,
                     "resolution": base.model_config().resolution, "batch": args.batch,
                     "workers": args.workers, "gpus_per_worker": gpus, "paper_test_mae": PAPER_TEST_MAE}  # fmt: skip

    def sink() -> None:
        (out / "figures.json").write_text(json.dumps(figures, indent=1))

    # the reference: one process, no Ray
    ref_steps = max(args.ref_steps, 20)
    ref_cfg = replace(base, out=str(out / "reference.pt"), steps=ref_steps, eval_every=ref_steps, eval_size=256)
    clock = _Clock(args.batch, skip=min(10, ref_steps // 2), echo=False, sink=sink)
    t0 = time.perf_counter()
    train(ref_cfg, progress=clock)
    figures["reference"] = {"steps": ref_steps, "seconds": round(time.perf_counter() - t0, 1),
                            "pairs_per_s": round(clock.pairs_per_s(), 1)}  # fmt: skip
    print(f"reference (one process, no Ray): {clock.pairs_per_s():,.0f} pairs/s", flush=True)
    sink()

    # the Ray Train run
    steps = math.ceil(args.pairs / args.batch)
    if args.budget_s > 0:
        steps = min(steps, max(ref_steps, int(args.budget_s * clock.pairs_per_s() / args.batch)))
    cfg = replace(base, out=str(out / "selfmodel.pt"), steps=steps, eval_every=max(1, steps // max(1, args.evals)))
    figures["ray"] = {"steps": steps, "pairs": steps * args.batch, "capped_by_budget": steps * args.batch < args.pairs}
    print(f"Ray Train: {args.workers} worker(s), {gpus:g} GPU each, {steps} steps of {args.batch} "
          f"= {steps * args.batch:,} pairs", flush=True)  # fmt: skip
    fanout = FanoutConfig(workers=args.workers, ray="local", cpus_per_worker=args.cpus_per_worker,
                          gpus_per_worker=gpus)  # fmt: skip
    clock = _Clock(args.batch, skip=min(50, steps // 4), echo=True, sink=sink)
    figures["ray"]["val_mae"] = clock.val
    t0 = time.perf_counter()
    metrics = fit_on_ray(functools.partial(train, cfg), cfg.out, "selfmodel", steps, fanout, clock)
    rate = clock.pairs_per_s()
    figures["ray"] |= {"seconds": round(time.perf_counter() - t0, 1), "pairs_per_s": round(rate, 1),
                       "test_mae": metrics.get("test_mae"), "final_val_mae": metrics.get("val_mae"),
                       "train_seconds": metrics.get("seconds")}  # fmt: skip
    figures["ray_over_reference"] = round(rate / figures["reference"]["pairs_per_s"], 3)
    figures["test_mae"] = metrics.get("test_mae")
    sink()
    print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    sys.exit(main())
