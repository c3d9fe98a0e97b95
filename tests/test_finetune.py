"""Learning from real shadows: capture sets on disk (round trip, typed errors, deterministic split, a capture loop
that survives an interruption), fine-tuning the shipped self-model through the one trainer (held-out MAE falls, the
checkpoint loads and names its capture set, cancel and resume), and the ``finetune`` verb's JSON line."""

from __future__ import annotations

import json
import math
import threading
from dataclasses import replace

import numpy as np
import pytest
import torch

from studio.errors import StudioError
from studio.learn.captures import (
    ARRAYS,
    RECORD,
    CaptureError,
    CaptureRecorder,
    CapturesCorrupt,
    CapturesMismatch,
    CapturesNotFound,
    load_captures,
    rendered_captures,
    save_captures,
    split,
)
from studio.learn.checkpoint import read_checkpoint
from studio.learn.finetune import CapturePairs, FinetuneConfig, finetune
from studio.learn.selfmodel import SelfModel, load_selfmodel
from studio.sim.shadow import Rig

torch.set_num_threads(1)
NOMINAL = Rig(resolution=128)  # the window the photographs are rectified into (the shipped model's)
TINY_RUN = dict(steps=30, batch_size=16, lr=1e-3, warmup=5, eval_every=15, held_out_fraction=0.25, threads=1)


def real_rig(resolution: int = 128) -> Rig:
    """The real rig the studio does not know: light nearer, mount rolled 4°, (foam thicker where Rig has it)."""
    kw = {"foam": 0.002} if "foam" in Rig.__dataclass_fields__ else {}
    return Rig(light=(0.0, 0.0, 2.7), roll=math.radians(4), resolution=resolution, **kw)


def photographed(hand, n: int, seed: int, resolution: int = 128):
    """``n`` captures of the real rig, rectified into the nominal window (the rig they record)."""
    return rendered_captures(n, real_rig(resolution), hand, seed=seed, rectified=NOMINAL)


@pytest.fixture(scope="module")
def capture_dir(tmp_path_factory, hand):
    return save_captures(tmp_path_factory.mktemp("captures") / "set", photographed(hand, 120, seed=3))


def test_capture_set_round_trip(tmp_path, hand):
    cs = photographed(hand, 12, seed=1)
    save_captures(tmp_path / "s", cs)
    back = load_captures(tmp_path / "s", hand.hash)
    assert len(back) == 12 and back.sha256 == cs.sha256 and back.rig == cs.rig and back.source == cs.source
    assert back.extra == {"true_rig": json.loads(json.dumps(real_rig().to_dict()))}
    np.testing.assert_array_equal(back.masks, cs.masks)
    np.testing.assert_array_equal(back.theta, cs.theta)
    assert back.masks.dtype == np.uint8 and back.theta.dtype == np.float32 and back.masks.shape == (12, 128, 128)
    rec = json.loads((tmp_path / "s" / RECORD).read_text())
    assert rec["format"] == "shadow-studio-captures" and rec["count"] == 12 and rec["window_m"] == 0.6
    assert rec["resolution"] == 128 and rec["hand_hash"] == hand.hash and rec["sha256"] == cs.sha256
    assert 0.02 < cs.masks.mean() < 0.5  # shadows, 1 = shadow


def test_capture_set_errors_are_typed_and_say_what(tmp_path, hand):
    with pytest.raises(CapturesNotFound, match="no capture set"):
        load_captures(tmp_path / "nowhere")
    cs = photographed(hand, 6, seed=2)
    folder = save_captures(tmp_path / "s", cs)
    with pytest.raises(CapturesMismatch, match="current hand"):
        load_captures(folder, "0000000000000000")
    arrays = (folder / ARRAYS).read_bytes()
    (folder / ARRAYS).write_bytes(arrays[: len(arrays) // 2])  # a half-copied file
    with pytest.raises(CapturesCorrupt, match="unreadable"):
        load_captures(folder)
    other = replace(cs, masks=1 - cs.masks)
    np.savez_compressed(folder / ARRAYS, theta=other.theta, masks=other.masks, t=other.t)  # arrays changed behind it
    with pytest.raises(CapturesCorrupt, match="does not match"):
        load_captures(folder)
    save_captures(folder, cs)
    rec = json.loads((folder / RECORD).read_text())
    (folder / RECORD).write_text(json.dumps(rec | {"version": 99}))
    with pytest.raises(CapturesCorrupt, match="version 99"):
        load_captures(folder)
    (folder / RECORD).write_text('{"format": "shadow-studio-captures", "vers')
    with pytest.raises(CapturesCorrupt, match="not valid JSON"):
        load_captures(folder)
    (folder / RECORD).unlink()
    with pytest.raises(CapturesNotFound, match=RECORD):
        load_captures(folder)
    with pytest.raises(CaptureError, match="binary"):
        replace(cs, masks=cs.masks * 255)


def test_split_is_deterministic_and_disjoint(hand):
    cs = photographed(hand, 50, seed=4)
    train, held = split(cs, 0.2, seed=5)
    again_train, again_held = split(cs, 0.2, seed=5)
    assert (len(train), len(held)) == (40, 10)
    assert train.sha256 == again_train.sha256 and held.sha256 == again_held.sha256
    assert set(train.t) | set(held.t) == set(cs.t) and not set(train.t) & set(held.t)
    assert np.all(np.diff(held.t) > 0)  # each part in capture order
    assert set(split(cs, 0.2, seed=6)[1].t) != set(held.t)
    with pytest.raises(ValueError, match="held_out_fraction"):
        split(cs, 1.0)


def test_capture_loop_saves_every_k_and_survives_an_interruption(tmp_path, hand):
    cs = photographed(hand, 7, seed=8)
    folder = tmp_path / "loop"
    with pytest.raises(KeyboardInterrupt):
        with CaptureRecorder(folder, cs.rig, hand.hash, "camera", save_every=3) as rec:
            for i in range(5):
                rec.append(cs.theta[i], cs.masks[i], cs.t[i])
                on_disk = len(load_captures(folder)) if folder.exists() else 0
                assert on_disk == 3 * ((i + 1) // 3)  # saved after the 3rd pair, not before
            raise KeyboardInterrupt  # the operator stops the session
    assert len(load_captures(folder)) == 5  # what was captured is kept
    with CaptureRecorder(folder, cs.rig, hand.hash, save_every=3) as rec:  # the next session continues the set
        for i in range(5, 7):
            rec.append(cs.theta[i], cs.masks[i], cs.t[i])
    assert load_captures(folder, hand.hash).sha256 == cs.sha256
    with pytest.raises(CapturesMismatch, match="another rig"):
        CaptureRecorder(folder, Rig(window=0.8, resolution=128).to_dict(), hand.hash)


def test_capture_pairs_resize_to_the_model(hand):
    cs = photographed(hand, 8, seed=9, resolution=256)
    train, held = split(cs, 0.25, seed=0)
    pairs = CapturePairs(train, held, 128, batch_size=4, seed=0)
    theta, masks = next(pairs.train_batches(0))
    assert theta.shape == (4, 21) and masks.shape == (4, 1, 128, 128) and pairs.rig["resolution"] == 128
    first = next(pairs.train_batches(3))[0]
    assert torch.equal(first, next(pairs.train_batches(3))[0])  # batch k is the same on resume
    (t_val, m_val), = pairs.held_out("val")  # fmt: skip
    full = torch.from_numpy(held.masks.astype(np.float32))
    assert torch.allclose(m_val[:, 0], full.reshape(2, 128, 2, 128, 2).mean(dim=(2, 4)))  # area, shadow share


def test_a_recorded_mount_roll_is_turned_back_into_the_hand_frame(hand):
    """Captures of a mount rolled on purpose (the rig records it) train the unrolled self-model (DESIGN §1)."""
    from studio.sim.shadow import ShadowRenderer

    rolled = Rig(resolution=128, roll=0.5)
    cs = rendered_captures(6, rolled, hand, seed=13, edge_flip=0.0, speckle=0.0)
    train, held = split(cs, 0.5, seed=0)
    pairs = CapturePairs(train, held, resolution=128, batch_size=3, seed=0)
    (theta, masks), = pairs.held_out("test")  # fmt: skip
    unrolled = ShadowRenderer(hand, NOMINAL).render(held.theta).astype(np.float32)
    assert "roll" not in pairs.rig and pairs.rig == NOMINAL.to_dict()
    as_photographed = np.abs(held.masks - unrolled).mean()
    assert np.abs(masks[:, 0].numpy() - unrolled).mean() < 0.2 * as_photographed, as_photographed


def test_tiny_finetune_lowers_held_out_mae_and_records_its_captures(tmp_path, hand, capture_dir):
    seen = []
    cfg = FinetuneConfig(out=str(tmp_path / "ft.pt"), captures=str(capture_dir), **TINY_RUN)
    result = finetune(cfg, hand, progress=seen.append)
    assert (result["pairs_train"], result["pairs_held_out"]) == (90, 30) and result["steps"] == 30
    assert result["mae_finetuned"] < 0.8 * result["mae_sim_only"], result
    assert {p.stage for p in seen} == {"train", "val", "test"}
    model, ckpt = load_selfmodel(cfg.out, hand, device="cpu")
    assert isinstance(model, SelfModel) and ckpt.rig == NOMINAL.to_dict()
    captures = load_captures(capture_dir)
    assert ckpt.extra["captures"]["sha256"] == captures.sha256 and ckpt.extra["captures"]["count"] == 120
    assert ckpt.metrics["mae_finetuned"] == result["mae_finetuned"] and ckpt.train["captures"] == str(capture_dir)
    with pytest.raises(StudioError, match="--resume"):
        finetune(cfg, hand)


def test_cancel_then_resume_and_guards(tmp_path, hand, capture_dir):
    cfg = FinetuneConfig(out=str(tmp_path / "ft.pt"), captures=str(capture_dir), **(TINY_RUN | {"steps": 6}))
    cancel = threading.Event()
    cut = finetune(cfg, hand, progress=lambda p: p.step == 2 and cancel.set(), cancel=cancel)
    assert cut["cancelled"] and cut["steps"] == 2 and cut["mae_finetuned"] is None
    assert read_checkpoint(cfg.out, "selfmodel", hand.hash).extra["step"] == 2
    other = save_captures(tmp_path / "other", photographed(hand, 8, seed=11))
    with pytest.raises(CapturesMismatch, match="another capture set"):
        finetune(replace(cfg, captures=str(other)), hand, resume=True)
    done = finetune(cfg, hand, resume=True)
    assert done["steps"] == 6 and done["mae_sim_only"] == cut["mae_sim_only"] and "cancelled" not in done
    wide = replace(photographed(hand, 8, seed=12), rig=Rig(window=0.8, resolution=128).to_dict())
    with pytest.raises(CapturesMismatch, match="window"):
        finetune(replace(cfg, captures=str(save_captures(tmp_path / "wide", wide))), hand, overwrite=True)


def test_finetune_verb_prints_one_json_line_last(tmp_path, in_process, capture_dir):
    out = tmp_path / "ft.pt"
    args = ["finetune", "--captures", capture_dir, "--out", out, "--steps", "3", "--eval-every", "3",
            "--batch-size", "8", "--held-out-fraction", "0.25", "--quiet"]  # fmt: skip
    run = in_process(*args)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout.strip().splitlines()[-1])
    for key in ("mae_sim_only", "mae_finetuned", "pairs_train", "pairs_held_out", "seconds"):
        assert key in summary, key
    assert (summary["pairs_train"], summary["pairs_held_out"]) == (90, 30) and out.is_file()
    missing = in_process("finetune", "--captures", tmp_path / "none", "--out", tmp_path / "x.pt", "--quiet")
    assert missing.returncode == 2 and len(missing.stderr.strip().splitlines()) == 1
    assert "no capture set" in missing.stderr
    bad = in_process("finetune", "--held-out-fraction", "1.5")
    assert bad.returncode == 2 and "--held-out-fraction" in bad.stderr
