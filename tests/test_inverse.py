"""Inverse-CNN baseline: its loss falls, predictions stay within the joint limits, checkpoints guard the hand."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from studio.assets import asset

from studio.cli.main import main
from studio.learn.checkpoint import CheckpointError, save_model
from studio.learn.config import CollectConfig, InverseConfig, InverseTrainConfig
from studio.learn.dataset import collect
from studio.learn.inverse import InverseCNN, load_inverse, train_inverse
from studio.sim.shadow import Rig, ShadowRenderer

TINY = InverseConfig(input_size=32, channels=(8, 16), hidden=32)
TINY_TRAIN = dict(resolution=32, steps=60, batch_size=32, eval_every=30, eval_size=128, lr=3e-3, warmup=5, threads=1)


def test_loss_falls_on_the_fly(tmp_path, hand):
    out = tmp_path / "inv.pt"
    metrics = train_inverse(InverseTrainConfig(out=str(out), **TINY_TRAIN), TINY, hand)
    assert metrics["val_mse"] < metrics["initial_val_mse"]
    assert metrics["train_mse"] < metrics["first_train_mse"]
    assert metrics["steps"] == 60 and out.is_file()


def test_trains_from_shards(tmp_path, hand):
    collect(tmp_path / "shards", CollectConfig(n=96, shard_size=96, resolution=32), hand)
    cfg = InverseTrainConfig(out=str(tmp_path / "inv.pt"), data=str(tmp_path / "shards"), **TINY_TRAIN | {"steps": 30})
    metrics = train_inverse(cfg, TINY, hand)
    assert metrics["train_mse"] < metrics["first_train_mse"]  # 67 training pairs: it memorises
    model, info = load_inverse(tmp_path / "inv.pt", hand)
    assert info.rig["resolution"] == 32 and info.metrics["steps"] == 30 and info.train["data"] == cfg.data


@pytest.mark.parametrize("scale", [1.0, 1000.0])
def test_predictions_within_limits(hand, rng, scale):
    torch.manual_seed(0)
    model = InverseCNN(TINY, hand)
    with torch.no_grad():
        model.head[-1].weight.mul_(scale)
        model.head[-1].bias.normal_(0, scale)
    shadows = (rng.random((5, 40, 40)) > 0.5).astype(np.uint8)
    theta = model.predict(shadows)
    assert theta.shape == (5, 21)
    assert np.all(theta >= hand.lower) and np.all(theta <= hand.upper)
    assert model.predict(shadows[0]).shape == (1, 21)  # one (H, W) image


def test_input_is_aligned_so_position_and_scale_do_not_matter(hand):
    model = InverseCNN(TINY, hand)
    theta = hand.rest_pose()
    small = ShadowRenderer(hand, Rig(resolution=64)).render_one(theta)
    big = ShadowRenderer(hand, Rig(resolution=128)).render_one(theta)
    shifted = np.roll(small, (5, -7), axis=(0, 1))
    a, b, c = model.crops(small[None]), model.crops(big[None]), model.crops(shifted[None])
    assert torch.allclose(a, c, atol=1e-5)
    assert (a - b).abs().mean() < 0.05


def test_checkpoint_round_trip_and_guards(tmp_path, hand, rng):
    model = InverseCNN(TINY, hand)
    path = tmp_path / "inv.pt"
    save_model(path, model, {"resolution": 32}, {"test_mse": 0.5})
    loaded, info = load_inverse(path, hand)
    shadows = (rng.random((3, 32, 32)) > 0.5).astype(np.float32)
    np.testing.assert_array_equal(loaded.predict(shadows), model.predict(shadows))
    assert info.metrics["test_mse"] == 0.5 and loaded.cfg == TINY and info.kind == "inverse"

    blob = torch.load(path, weights_only=True)
    blob["hand_hash"] = "another-hand"
    torch.save(blob, path)
    with pytest.raises(CheckpointError, match="current hand"):
        load_inverse(path, hand)
    with pytest.raises(CheckpointError, match="inverse-CNN checkpoint not found") as info:
        load_inverse(tmp_path / "missing.pt", hand)
    assert info.value.kind == "inverse"  # the command line names the verb from it (studio.cli.runs.advice)
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="unreadable"):
        load_inverse(tmp_path / "junk.pt", hand)
    with pytest.raises(CheckpointError, match="of the self-model, not of the inverse-CNN"):
        load_inverse(asset("models/selfmodel_cpu128.pt"), hand)


def test_shipped_inverse_loads_in_the_current_format(hand):
    model, info = load_inverse(asset("models/inverse_cpu128.pt"), hand)
    assert info.kind == "inverse" and model.cfg == InverseConfig() and info.metrics["test_mse"] < 0.4
    assert info.rig["resolution"] == 128 and info.train["steps"] == info.metrics["steps"] == 15000


def test_train_inverse_cli(tmp_path, capsys):
    out = tmp_path / "inv.pt"
    args = ["train-inverse", "--out", str(out), "--resolution", "32", "--input-size", "16", "--steps", "3",
            "--eval-every", "3", "--eval-size", "16", "--threads", "1", "--quiet"]  # fmt: skip
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["checkpoint"] == str(out) and summary["steps"] == 3
    assert main(args) == 2  # refuses to replace it without --force (or continue it without --resume)
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--force" in err and "--resume" in err
    assert main(args + ["--steps", "5", "--resume"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["steps"] == 5
    assert main(args + ["--force"]) == 0
    with pytest.raises(SystemExit) as exit_:
        main(["train-inverse", "--eval-every", "0"])
    assert exit_.value.code == 2 and "--eval-every" in capsys.readouterr().err
