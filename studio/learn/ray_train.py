"""The one trainer on Ray Train: ``train --ray --workers N [--gpus-per-worker G]``.

:func:`fit_on_ray` starts Ray Train's ``TorchTrainer`` with ``N`` workers (DDP over gloo on CPUs, NCCL on GPUs; the
process group is Ray Train's) and runs the same training call in each (``run(progress=, cancel=, replica=)``, e.g.
``functools.partial(studio.learn.train.train, cfg)``): :func:`studio.learn.trainer.fit` with a
:class:`~studio.learn.trainer.Replica`, so every worker takes its rows of each global batch (on the fly it renders
only those), the gradients are averaged and each step equals the single process's step on the whole batch. The
checkpoint is the one format, written by worker 0 to ``cfg.out`` (on a cluster: a path every machine sees), so
``--resume`` continues it exactly, with Ray or without.

Progress comes back from worker 0 through a small relay actor and is reported here (the one progress protocol);
``cancel`` (Ctrl-C) is passed to worker 0, every worker stops at the same step and worker 0 leaves a resumable
checkpoint. The metrics returned are the checkpoint's (``cancelled: True`` when it stopped early). Ray (and Ray
Train) are imported only here and in :mod:`studio.learn.ray_cluster`, and only for ``--ray`` (DESIGN §3).
"""

from __future__ import annotations

import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import ray
from ray.train import RunConfig, ScalingConfig
from ray.train.torch import TorchTrainer

from studio.errors import Progress, ProgressFn, StudioError, stopped
from studio.learn.checkpoint import read_checkpoint
from studio.learn.fanout import FanoutConfig
from studio.learn.ray_cluster import ray_for
from studio.learn.trainer import Replica

__all__ = ["fit_on_ray"]

POLL_S = 0.3  # how often the driver forwards progress and passes on a cancel, s
CANCEL_POLL_S = 0.5  # how often worker 0 asks the relay whether to stop, s


class _Relay:
    """Progress from worker 0 to the driver, and the driver's cancel to worker 0 (an actor)."""

    def __init__(self) -> None:
        self.events: list[Progress] = []
        self.cancelled = False

    def push(self, p: Progress) -> None:
        self.events.append(p)

    def take(self) -> list[Progress]:
        out, self.events = self.events, []
        return out

    def cancel(self) -> None:
        self.cancelled = True

    def is_cancelled(self) -> bool:
        return self.cancelled


class _RelayCancel:
    """A cancel event for the trainer that asks the relay, at most every ``CANCEL_POLL_S``."""

    def __init__(self, relay) -> None:
        self.relay, self.seen, self.last = relay, False, 0.0

    def is_set(self) -> bool:
        if not self.seen and time.monotonic() - self.last >= CANCEL_POLL_S:
            self.last = time.monotonic()
            self.seen = bool(ray.get(self.relay.is_cancelled.remote()))
        return self.seen


def _worker(config: dict) -> None:
    """One Ray Train worker: the training call as replica ``rank`` of ``world``, in the driver's working folder
    where this machine has it (Ray Train starts each worker in a folder of its own, where a relative ``--out``,
    ``--data`` or ``--rig-file`` would name files the driver never sees)."""
    if os.path.isdir(config["cwd"]):
        os.chdir(config["cwd"])
    ctx = ray.train.get_context()
    replica = Replica(ctx.get_world_rank(), ctx.get_world_size())
    relay = config["relay"]
    progress = (lambda p: relay.push.remote(p)) if replica.main else None
    cancel = _RelayCancel(relay) if replica.main else None
    config["run"](progress=progress, cancel=cancel, replica=replica)


def fit_on_ray(
    run: Callable[..., dict],
    out: str | Path,
    kind: str,
    steps: int,
    fanout: FanoutConfig,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> dict:
    """``run`` on ``fanout.workers`` Ray Train workers (module doc); the metrics of the ``kind`` checkpoint it
    wrote to ``out`` (``cancelled: True`` when it holds fewer than ``steps`` steps)."""
    cpus, gpus = fanout.cpus_per_worker, fanout.gpus_per_worker
    with ray_for(fanout.ray or "local", fanout.workers * cpus, fanout.workers * gpus):
        relay = ray.remote(num_cpus=0)(_Relay).remote()
        storage = Path(tempfile.mkdtemp(prefix="studio-ray-train-"))  # Ray Train's own records (not the checkpoint)
        trainer = TorchTrainer(
            _worker,
            train_loop_config={"run": run, "relay": relay, "cwd": os.getcwd()},
            scaling_config=ScalingConfig(num_workers=fanout.workers, use_gpu=gpus > 0,
                                         resources_per_worker={"CPU": cpus} | ({"GPU": gpus} if gpus else {})),
            run_config=RunConfig(storage_path=str(storage), name="train"),
        )  # fmt: skip
        failure: list[BaseException] = []

        def fit() -> None:
            try:
                trainer.fit()
            except Exception as e:  # reported below, in the caller's thread
                failure.append(e)

        thread = threading.Thread(target=fit, name="ray-train", daemon=True)
        thread.start()
        asked = False
        try:
            while thread.is_alive():
                thread.join(POLL_S)
                if stopped(cancel) and not asked:
                    relay.cancel.remote()
                    asked = True
                for p in ray.get(relay.take.remote()):
                    if progress is not None:
                        progress(p)
            for p in ray.get(relay.take.remote()):
                if progress is not None:
                    progress(p)
        finally:
            ray.kill(relay)
            shutil.rmtree(storage, ignore_errors=True)
    if failure:
        e = failure[0]
        cause = getattr(e, "worker_failures", None) or getattr(e, "cause", None) or e
        raise StudioError(f"training on Ray failed: {cause}") from e
    ckpt = read_checkpoint(out, kind)
    done = int(ckpt.extra.get("step", steps))
    return dict(ckpt.metrics) | ({"cancelled": True} if done < steps else {})
