"""Self-model: shapes, gradients to θ, a tiny model trains, checkpoints round-trip and guard the hand."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from studio.errors import StudioError
from studio.learn.selfmodel import (
    CheckpointError,
    SelfModel,
    SelfModelConfig,
    load_selfmodel,
    read_checkpoint,
)
from studio.learn.train import TrainConfig, lr_at, train

TINY = dict(resolution=32, hidden=64, channels=16, min_channels=8, res_blocks=1)


@pytest.mark.parametrize("inp", ["fk", "theta"])
def test_shapes_and_range(hand, inp):
    model = SelfModel(SelfModelConfig(input=inp, **TINY), hand)
    theta = torch.tensor(np.stack([hand.rest_pose()] * 3), dtype=torch.float32)
    out = model(theta)
    assert out.shape == (3, 1, 32, 32)
    assert torch.all((out >= 0) & (out <= 1))


def test_paper_architecture_has_five_upsamplings(hand):
    model = SelfModel(SelfModelConfig(), hand)
    ups = [m for m in model.modules() if isinstance(m, torch.nn.ConvTranspose2d)]
    assert len(ups) == 5 and model.mlp[0].in_features == 336
    assert model(torch.zeros(1, 21)).shape == (1, 1, 256, 256)


def test_gradients_reach_theta_through_fk(hand):
    model = SelfModel(SelfModelConfig(**TINY), hand)
    theta = torch.zeros(2, 21, requires_grad=True)
    model(theta).mean().backward()
    assert theta.grad is not None and torch.isfinite(theta.grad).all()
    assert (theta.grad.abs() > 0).sum() >= 15  # nearly every joint moves some part of the shell


def test_bad_config_rejected():
    with pytest.raises(ValueError, match="resolution"):
        SelfModelConfig(resolution=100)
    with pytest.raises(ValueError, match="input"):
        SelfModelConfig(input="pixels")


def test_lr_schedule_warms_up_and_decays():
    cfg = TrainConfig(steps=1000, warmup=100, lr=1e-3)
    assert lr_at(0, cfg) < lr_at(99, cfg) == pytest.approx(1e-3)
    assert lr_at(500, cfg) < 1e-3 and lr_at(999, cfg) == pytest.approx(2e-5, rel=0.05)


def test_tiny_model_trains_resumes_and_reloads(tmp_path, hand):
    out = tmp_path / "tiny.pt"
    cfg = TrainConfig(out=str(out), resolution=32, steps=60, batch_size=32, warmup=5, eval_every=30,
                      eval_size=128, lr=3e-3, threads=1)  # fmt: skip
    first = train(cfg, hand)
    assert first["test_mae"] < 0.45  # an untrained decoder outputs ~0.5 everywhere
    model, info = load_selfmodel(out, hand, device="cpu")
    assert info.metrics["test_mae"] == pytest.approx(first["test_mae"])
    assert info.config.resolution == 32 and info.hand_hash == hand.hash
    with pytest.raises(StudioError, match="--resume"):
        train(cfg, hand)
    longer = train(TrainConfig(**{**cfg.__dict__, "steps": 120}), hand, resume=True)
    assert longer["steps"] == 120
    assert longer["test_mae"] < 0.9 * first["val_mae"] or longer["test_mae"] < first["test_mae"]


def test_loss_falls_in_seconds(hand):
    torch.manual_seed(0)
    model = SelfModel(SelfModelConfig(**TINY), hand)
    from studio.learn.dataset import OnTheFlyBatches

    opt = torch.optim.Adam(model.parameters(), 3e-3)
    losses = []
    for theta, masks in OnTheFlyBatches(batch_size=32, resolution=32, num_batches=80, hand=hand):
        loss = (model(theta) - masks).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert np.mean(losses[-10:]) < 0.6 * np.mean(losses[:5])


def test_checkpoint_errors(tmp_path, hand):
    with pytest.raises(CheckpointError, match="not found"):
        read_checkpoint(tmp_path / "absent.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="unreadable"):
        read_checkpoint(junk)
    torch.save({"hello": 1}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not a shadow-studio"):
        read_checkpoint(tmp_path / "other.pt")


def test_checkpoint_for_another_hand_refused(tmp_path, hand):
    from studio.learn.selfmodel import Checkpoint, save_checkpoint

    model = SelfModel(SelfModelConfig(**TINY), hand)
    save_checkpoint(tmp_path / "m.pt", model, Checkpoint(model.cfg, "ffffffffffffffff", {}))
    with pytest.raises(CheckpointError, match="retrain"):
        load_selfmodel(tmp_path / "m.pt", hand)
