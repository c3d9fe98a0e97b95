"""Training on a real local Ray (two CPUs) through Ray Train: the same loss curve as one process at the same global
batch, a cancelled run that resumes to the same weights, and the verb's flags."""

from __future__ import annotations

import json
import threading
from functools import partial

import numpy as np
import pytest
import ray  # a dependency (pyproject): a missing install fails here, never skips
import torch

from studio.cli.main import main
from studio.fanout import FanoutConfig
from studio.learn.checkpoint import read_checkpoint
from studio.learn.config import TrainConfig
from studio.learn.train import train

pytestmark = pytest.mark.slow
ON_RAY = FanoutConfig(workers=2, ray="local")


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


def tiny(out, steps: int = 8) -> TrainConfig:
    """A 16² self-model rendered on the fly: global batch 8, validation every 4 steps."""
    return TrainConfig(out=str(out), model="cpu", resolution=16, steps=steps, batch_size=8, warmup=2, eval_every=4,
                       eval_size=16, threads=1, device="cpu")  # fmt: skip


def losses() -> tuple[list[float], callable]:
    seen: list[float] = []

    def progress(p) -> None:
        if p.stage == "train":
            seen.append(p.best)

    return seen, progress


def weights(path) -> dict[str, torch.Tensor]:
    return read_checkpoint(path, "selfmodel").state_dict


def test_ray_train_follows_one_process_and_a_cancelled_run_resumes_exactly(tmp_path, hand, local_ray, capsys):
    """Two Ray Train workers at the same global batch as one process: the same running loss step by step and the
    same weights, even when the Ray run is cancelled after a few steps and resumed to the end by `train --ray`."""
    from studio.learn.ray_train import fit_on_ray

    whole, seen_whole = tiny(tmp_path / "whole.pt", steps=40), losses()
    reference = train(whole, hand, progress=seen_whole[1])
    parts, seen_parts = tiny(tmp_path / "parts.pt", steps=40), losses()
    cancel = threading.Event()

    def stop_soon(p) -> None:
        seen_parts[1](p)
        if p.stage == "train" and p.step >= 2:
            cancel.set()

    cut = fit_on_ray(partial(train, parts), parts.out, "selfmodel", parts.steps, ON_RAY, stop_soon, cancel)
    done = read_checkpoint(parts.out, "selfmodel").extra["step"]
    assert cut.get("cancelled") is True and 2 <= done < parts.steps and len(seen_parts[0]) == done
    np.testing.assert_allclose(seen_parts[0], seen_whole[0][:done], rtol=1e-3)  # the loss, step by step
    assert main([*verb(parts.out, parts.steps), "--resume", "--workers", "2", "--ray"]) == 0  # the verb resumes it
    resumed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "cancelled" not in resumed and resumed["steps"] == parts.steps
    assert resumed["train_mae"] == pytest.approx(reference["train_mae"], rel=1e-3)
    assert resumed["test_mae"] == pytest.approx(reference["test_mae"], rel=1e-3)
    for k, w in weights(whole.out).items():
        torch.testing.assert_close(weights(parts.out)[k], w, rtol=1e-3, atol=1e-4)


def verb(out, steps: int) -> list[str]:
    """`shadow-studio train` with the flags of :func:`tiny`."""
    return ["train", "--out", str(out), "--resolution", "16", "--steps", str(steps), "--batch-size", "8",
            "--warmup", "2", "--eval-every", "4", "--eval-size", "16", "--threads", "1", "--device", "cpu",
            "--quiet"]  # fmt: skip


def test_the_train_verbs_refusals_come_before_ray_starts(tmp_path, capsys):
    out = tmp_path / "m.pt"
    assert main([*verb(out, 4), "--workers", "2"]) == 2  # workers without Ray: one line saying to add --ray
    assert "add --ray" in capsys.readouterr().err
    assert main([*verb(out, 4), "--workers", "3", "--ray"]) == 2  # 8 does not split over 3 workers
    err = capsys.readouterr().err
    assert "does not split evenly over 3 workers" in err and "Traceback" not in err
    out.write_bytes(b"")
    assert main([*verb(out, 4), "--workers", "2", "--ray"]) == 2  # exists: --resume or --force
    assert "--resume" in capsys.readouterr().err
