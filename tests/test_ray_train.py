"""Training on a real local Ray (two CPUs) through Ray Train: `train --ray` stopped by Ctrl-C resumes to the one
process's weights, and the verb's refusals come before Ray starts."""

from __future__ import annotations

import json

import pytest
import ray  # a dependency (pyproject): a missing install fails here, never skips
import torch
from ctrl_c_support import ctrl_c_once_written  # this folder's helper

from studio.cli.main import main
from studio.learn.checkpoint import read_checkpoint
from studio.learn.config import TrainConfig
from studio.learn.train import train

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


def tiny(out, steps: int = 8) -> TrainConfig:
    """A 16² self-model rendered on the fly: global batch 8, validation every 4 steps."""
    return TrainConfig(out=str(out), model="cpu", resolution=16, steps=steps, batch_size=8, warmup=2, eval_every=4,
                       eval_size=16, threads=1, device="cpu")  # fmt: skip


def weights(path) -> dict[str, torch.Tensor]:
    return read_checkpoint(path, "selfmodel").state_dict


def test_train_on_ray_stopped_by_ctrl_c_resumes_to_the_one_process_weights(tmp_path, hand, local_ray, capsys):
    """`train --ray` on two Ray Train workers at the same global batch as one process, stopped by Ctrl-C after its
    first checkpoint: it reports the steps it made, exits 130 and leaves a checkpoint that `train --resume` (one
    process) continues to the end, to the one process's weights and metrics (so every Ray step was the one process's
    step)."""
    whole = tiny(tmp_path / "whole.pt", steps=40)
    reference = train(whole, hand)
    parts = tmp_path / "parts.pt"
    with ctrl_c_once_written(parts):  # the first checkpoint: step 4 of 40
        code = main([*verb(parts, 40, quiet=False), "--workers", "2", "--ray"])
    captured = capsys.readouterr()
    cut = json.loads(captured.out.strip().splitlines()[-1])
    done = read_checkpoint(parts, "selfmodel").extra["step"]
    assert code == 130 and cut["cancelled"] is True and 4 <= done < 40 and cut["steps"] == done
    assert f"{done}/40" in captured.err  # worker 0's progress reached the verb's bar, to the step it stopped at
    assert main([*verb(parts, 40), "--resume"]) == 0
    resumed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "cancelled" not in resumed and resumed["steps"] == 40
    assert resumed["train_mae"] == pytest.approx(reference["train_mae"], rel=1e-3)
    assert resumed["test_mae"] == pytest.approx(reference["test_mae"], rel=1e-3)
    for k, w in weights(whole.out).items():
        torch.testing.assert_close(weights(parts)[k], w, rtol=1e-3, atol=1e-4)


def verb(out, steps: int, quiet: bool = True) -> list[str]:
    """`shadow-studio train` with the flags of :func:`tiny` (``quiet``: no progress bar)."""
    return ["train", "--out", str(out), "--resolution", "16", "--steps", str(steps), "--batch-size", "8",
            "--warmup", "2", "--eval-every", "4", "--eval-size", "16", "--threads", "1", "--device", "cpu",
            *(["--quiet"] if quiet else [])]  # fmt: skip


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
