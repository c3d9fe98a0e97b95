"""Self-model: shapes, gradients to θ, a tiny model trains (resumes, cancels), checkpoints round-trip and guard
the kind and the hand; the shipped checkpoint loads."""

from __future__ import annotations

import json
import threading
from dataclasses import astuple

import numpy as np
import pytest
import torch
from ctrl_c_support import ctrl_c_once_written  # this folder's helper
from studio.assets import asset

from studio.cli.main import main
from studio.cli.runs import advice
from studio.errors import Progress, StudioError
from studio.learn.checkpoint import CheckpointError, read_checkpoint, save_model
from studio.learn.config import TrainConfig
from studio.learn.pairs import BatchesAhead, Pairs
from studio.learn.selfmodel import SelfModel, SelfModelConfig, load_selfmodel
from studio.learn.train import train
from studio.learn.trainer import lr_at

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


@pytest.mark.slow
def test_batches_made_ahead_are_the_stream_itself(hand):
    """The background thread hands over the same on-the-fly batches in the same order (uint8 shadows, cast by
    ``fit`` on its device), raises the source's failure where it happened, and ends when closed."""
    pairs = Pairs(TrainConfig(batch_size=6, resolution=32), hand, 32)
    ahead = BatchesAhead(pairs.train_batches(4))
    for want in [next(pairs.train_batches(k)) for k in (4, 5, 6)]:
        got = next(ahead)
        assert got[1].dtype == torch.uint8 and torch.equal(got[0], want[0]) and torch.equal(got[1], want[1])
    ahead.close()
    assert not ahead.thread.is_alive()

    def failing():
        yield from [(torch.zeros(1), torch.zeros(1))] * 2
        raise ValueError("shard 3 is unreadable")

    ahead = BatchesAhead(failing())
    next(ahead), next(ahead)
    with pytest.raises(ValueError, match="shard 3"):
        next(ahead)
    ahead.close()


def test_tiny_model_trains_resumes_and_reloads(tmp_path, hand):
    out = tmp_path / "tiny.pt"
    cfg = TrainConfig(out=str(out), resolution=32, steps=60, batch_size=32, warmup=5, eval_every=30,
                      eval_size=128, lr=3e-3, threads=1)  # fmt: skip
    seen = []
    first = train(cfg, hand, progress=seen.append)
    assert first["test_mae"] < 0.45 < first["initial_val_mae"]  # an untrained decoder outputs ~0.5 everywhere
    assert all(isinstance(p, Progress) for p in seen)
    assert [p.stage for p in seen].count("train") == 60 and ("val", 30, 60) == astuple(seen[29 + 1])[:3]
    assert astuple(seen[-1])[:3] == ("test", 60, 60) and seen[-1].best == first["test_mae"]
    model, info = load_selfmodel(out, hand, device="cpu")
    assert info.metrics["test_mae"] == pytest.approx(first["test_mae"])
    assert info.kind == "selfmodel" and info.config["resolution"] == 32 and info.hand_hash == hand.hash
    assert info.train["steps"] == 60 and "optimizer" not in info.extra  # a finished run keeps no optimiser
    with pytest.raises(StudioError, match="--resume"):
        train(cfg, hand)
    longer = train(TrainConfig(**{**cfg.__dict__, "steps": 120}), hand, resume=True)
    assert longer["steps"] == 120
    assert longer["test_mae"] < 0.9 * first["val_mae"] or longer["test_mae"] < first["test_mae"]
    with pytest.raises(CheckpointError, match="architecture"):
        train(TrainConfig(**{**cfg.__dict__, "input": "theta"}), hand, resume=True)
    again = train(TrainConfig(**{**cfg.__dict__, "steps": 2, "eval_every": 1}), hand, overwrite=True)
    assert again["steps"] == 2 and read_checkpoint(out, "selfmodel").extra["step"] == 2


@pytest.mark.slow
def test_resume_after_cancel_continues_exactly(tmp_path, hand):
    """A run cancelled at step 7 and resumed ends with the same weights as one that ran straight through."""
    common = dict(resolution=16, steps=12, batch_size=8, warmup=2, eval_every=4, eval_size=16, lr=3e-3, threads=1)
    whole = tmp_path / "whole.pt"
    train(TrainConfig(out=str(whole), **common), hand)

    parts = tmp_path / "parts.pt"
    cancel = threading.Event()
    stop_at_7 = lambda p: p.step == 7 and cancel.set()  # noqa: E731
    cut = train(TrainConfig(out=str(parts), **common), hand, progress=stop_at_7, cancel=cancel)
    assert cut["cancelled"] and cut["steps"] == 7 and "test_mae" not in cut
    ckpt = read_checkpoint(parts, "selfmodel", hand.hash)
    assert ckpt.extra["step"] == 7 and "optimizer" in ckpt.extra
    train(TrainConfig(out=str(parts), **common), hand, resume=True)
    a, b = read_checkpoint(whole, "selfmodel").state_dict, read_checkpoint(parts, "selfmodel").state_dict
    assert set(a) == set(b)
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=1e-5, atol=1e-6)


@pytest.mark.slow
def test_ctrl_c_stops_the_train_verb_within_a_step_and_resume_finishes_it(tmp_path, capsys):
    """`train` in one process: the first Ctrl-C stops the run within its step and leaves a checkpoint of the step it
    reached (not only of the last validation), the summary says so and the exit status is 130; `--resume` ends it."""
    out = tmp_path / "m.pt"
    verb = ["train", "--out", str(out), "--resolution", "16", "--steps", "60", "--batch-size", "8", "--warmup", "2",
            "--eval-every", "4", "--eval-size", "16", "--threads", "1", "--device", "cpu", "--quiet"]  # fmt: skip
    with ctrl_c_once_written(out):  # the first checkpoint: step 4 of 60
        code = main(verb)
    cut = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    ckpt = read_checkpoint(out, "selfmodel")
    assert code == 130 and cut["cancelled"] is True and 4 <= cut["steps"] < 60
    assert ckpt.extra["step"] == cut["steps"] and "optimizer" in ckpt.extra
    assert main([*verb, "--resume"]) == 0
    done = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert done["steps"] == 60 and "cancelled" not in done


def test_bad_training_options_are_refused(hand):
    for bad, match in (({"eval_every": 0}, "eval_every"), ({"steps": 0}, "steps"), ({"lr": 0.0}, "lr"),
                       ({"batch_size": 0}, "batch_size"), ({"model": "huge"}, "model"),
                       ({"resolution": 100}, "resolution"), ({"input": "pixels"}, "input")):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            TrainConfig(**bad)


def test_train_cli_ranges_and_run(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:  # was a ZeroDivisionError
        main(["train", "--eval-every", "0"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--eval-every" in err and "must be in [1, " in err
    out = tmp_path / "m.pt"
    args = ["train", "--out", str(out), "--resolution", "16", "--steps", "2", "--eval-every", "1", "--eval-size", "8",
            "--batch-size", "4", "--threads", "1", "--quiet"]  # fmt: skip
    assert main(args) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["checkpoint"] == str(out) and summary["steps"] == 2
    assert main(args) == 2 and "--resume" in capsys.readouterr().err
    assert main(args + ["--force"]) == 0


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
    with pytest.raises(CheckpointError, match="not found") as info:
        read_checkpoint(tmp_path / "absent.pt", "selfmodel")
    # the engine names no command; the command line says which verb makes one
    assert "shadow-studio" not in str(info.value) and "--" not in str(info.value)
    assert advice(info.value) == " (shadow-studio train --out PATH makes one)"
    with pytest.raises(CheckpointError) as info:
        read_checkpoint(tmp_path / "absent.pt", "inverse")
    assert "inverse-CNN" in str(info.value) and "train-inverse" in advice(info.value)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="unreadable"):
        read_checkpoint(junk, "selfmodel")
    torch.save({"hello": 1}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not a shadow-studio"):
        read_checkpoint(tmp_path / "other.pt", "selfmodel")


def test_checkpoint_for_another_hand_or_kind_refused(tmp_path, hand):
    model = SelfModel(SelfModelConfig(**TINY), hand)
    save_model(tmp_path / "m.pt", model, {})
    blob = torch.load(tmp_path / "m.pt", weights_only=True)
    blob["hand_hash"] = "ffffffffffffffff"
    torch.save(blob, tmp_path / "m.pt")
    with pytest.raises(CheckpointError, match="retrain"):
        load_selfmodel(tmp_path / "m.pt", hand)
    with pytest.raises(CheckpointError, match="of the inverse-CNN, not of the self-model"):
        load_selfmodel(asset("models/inverse_cpu128.pt"), hand)


def test_checkpoint_round_trip_is_exact(tmp_path, hand):
    torch.manual_seed(3)
    model = SelfModel(SelfModelConfig(**TINY), hand).eval()
    save_model(tmp_path / "m.pt", model, {"resolution": 32}, {"test_mae": 0.1})
    loaded, info = load_selfmodel(tmp_path / "m.pt", hand, device="cpu")
    theta = torch.tensor(np.stack([hand.rest_pose(), hand.lower * 0.5]), dtype=torch.float32)
    with torch.no_grad():
        assert torch.equal(model(theta), loaded(theta))
    assert info.rig == {"resolution": 32} and info.metrics == {"test_mae": 0.1} and info.state_dict == {}
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_shipped_model_loads_in_the_current_format(hand):
    model, info = load_selfmodel(asset("models/selfmodel_cpu128.pt"), hand, device="cpu")
    assert info.kind == "selfmodel" and model.cfg.resolution == 128 and info.metrics["test_mae"] < 0.01
    assert info.rig["resolution"] == 128 and info.train["model"] == "cpu"
