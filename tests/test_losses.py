"""studio.sim.crop, .clip_loss, .losses: values on hand-made masks, crop invariances, gradients, CLIP."""

from __future__ import annotations

import argparse
import json
import math
import re
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from studio.cli.clip_flags import add_clip_arguments, clip_from_args
from studio.errors import StudioError
from studio.imitate.clip_files import KNOWN_SOURCES, cache_candidates
from studio.imitate.clip_loss import TINY_CLIP_CFG, ClipWeightsError, find_clip, load_clip, tiny_clip
from studio.imitate.config import COMPONENTS, LossConfig
from studio.imitate.losses import ImageLoss, mae, soft_iou, temporal_loss
from studio.sim.crop import align, as_image_batch, pad_pixels, square_boxes
from studio.targets.holes import find_holes
from studio.targets.images import load_target, shadow_box, square_frame

CFG = LossConfig(crop_size=64)  # small crops: CPU tests in milliseconds


@pytest.fixture(scope="module")
def clip():
    return tiny_clip(seed=0)


def _ellipse(h: int, w: int, centre: tuple[float, float], axes: tuple[float, float], angle: float = 0.0) -> np.ndarray:
    """A filled ellipse ``(h, w)`` uint8, drawn with 1/16-pixel precision."""
    m = np.zeros((h, w), np.uint8)
    c = (int(round(centre[0] * 16)), int(round(centre[1] * 16)))
    ax = (int(round(axes[0] * 16)), int(round(axes[1] * 16)))
    cv2.ellipse(m, c, ax, angle, 0, 360, 1, -1, lineType=cv2.LINE_8, shift=4)
    return m


def _shape() -> torch.Tensor:
    """A target with an opening: a 64² frame holding a ring and a bar."""
    m = _ellipse(64, 64, (30, 30), (20, 16)) - _ellipse(64, 64, (30, 30), (8, 6))
    m[44:58, 26:34] = 1
    return torch.from_numpy(m.astype(np.float32))


def test_basic_terms_on_hand_made_masks() -> None:
    a = torch.zeros(1, 4, 4)
    a[0, :2] = 1  # top half
    b = torch.zeros(1, 4, 4)
    b[0, :, :2] = 1  # left half
    assert soft_iou(a, a).item() == pytest.approx(1.0)
    assert soft_iou(a, b).item() == pytest.approx(4 / 12)  # overlap 4, union 12
    assert soft_iou(a, 1 - a).item() == pytest.approx(0.0, abs=1e-6)
    assert soft_iou(torch.zeros(1, 4, 4), torch.zeros(1, 4, 4)).item() == pytest.approx(1.0)
    assert mae(a, b).item() == pytest.approx(0.5)
    half = torch.full((1, 4, 4), 0.5)
    assert soft_iou(half, half).item() == pytest.approx(1.0)  # soft images: identical still means IoU 1
    theta = torch.tensor([[0.1, -0.2, 0.0]])
    assert temporal_loss(theta, torch.zeros(3)).item() == pytest.approx(0.2 * 0.05)


def test_identical_masks_give_zero_loss(clip) -> None:
    t = _shape()
    loss = ImageLoss(t, CFG, clip=clip, expressive=torch.from_numpy(find_holes(t.numpy().astype(np.uint8))))
    total, comp = loss(torch.stack([t, t])[:, None], theta=torch.zeros(2, 21), theta_prev=torch.zeros(21))
    assert set(comp) == set(COMPONENTS)
    for name, value in comp.items():
        assert value.shape == (2,)
        assert value.abs().max().item() < 1e-5, name
    assert total.abs().max().item() < 1e-5


def test_disjoint_masks_give_iou_loss_one(clip) -> None:
    """Two dots on one diagonal against two on the other: the same aligned box, no common pixel."""
    t = torch.zeros(64, 64)
    t[10:20, 10:20] = t[40:50, 40:50] = 1
    p = torch.zeros(64, 64)
    p[10:20, 40:50] = p[40:50, 10:20] = 1
    _, comp = ImageLoss(t, CFG, clip=clip)(p[None])
    assert comp["iou_loss"].item() == pytest.approx(1.0, abs=1e-4)
    assert comp["mae"].item() > 0.05
    empty = torch.zeros(1, 64, 64)
    assert ImageLoss(t, CFG, clip=clip)(empty)[1]["iou_loss"].item() == pytest.approx(1.0, abs=1e-6)


@settings(max_examples=30, deadline=None)
@given(
    dy=st.integers(-20, 20),
    dx=st.integers(-20, 20),
    axes=st.tuples(st.floats(6, 20), st.floats(6, 20)),
    angle=st.floats(0, 180),
)
def test_crop_is_translation_invariant(dy: int, dx: int, axes: tuple[float, float], angle: float) -> None:
    a = _ellipse(96, 96, (48, 48), axes, angle)
    b = _ellipse(96, 96, (48 + dx, 48 + dy), axes, angle)  # the same shape moved by whole pixels
    crops, _ = align(np.stack([a, b]), size=48)
    assert (crops[0] - crops[1]).abs().max().item() < 1e-4
    loss = ImageLoss(a, LossConfig(crop_size=48, use_clip=False))
    assert loss(b[None])[1]["total"].item() < 1e-5


@settings(max_examples=25, deadline=None)
@given(
    scale=st.floats(1.2, 2.5),
    axes=st.tuples(st.floats(15, 25), st.floats(15, 25)),
    angle=st.floats(0, 180),
    pad=st.sampled_from([0.0, 5.0]),
)
def test_crop_is_nearly_scale_invariant(scale: float, axes: tuple[float, float], angle: float, pad: float) -> None:
    """A shape and the same shape ``scale`` times larger align; the fixed pad is the only systematic difference."""
    small = _ellipse(200, 200, (45, 50), axes, angle)
    big = _ellipse(200, 200, (110, 110), (axes[0] * scale, axes[1] * scale), angle)
    cfg = LossConfig(crop_size=64, pad=pad, use_clip=False)
    comp = ImageLoss(big, cfg)(small[None])[1]
    # the fixed pad frames the small shape with relatively more backdrop: its crop is the big one's shrunk by r
    p = pad_pixels(pad, 200, 200)
    fill = [(lambda b: max(b[1] - b[0], b[3] - b[2]))(shadow_box(m)) for m in (small, big)]
    r = (fill[0] / (fill[0] + 2 * p)) / (fill[1] / (fill[1] + 2 * p))
    # the rest: each box is whole pixels (±1 px of the small side L moves the scale by 1/L) and edge resampling
    assert comp["iou_loss"].item() < 1 - r**2 + 3 / fill[0] + 0.02
    other = np.zeros((200, 200), np.uint8)
    other[20:180, 60:68] = 1  # a thin bar: a different shape scores far worse
    assert ImageLoss(big, cfg)(other[None])[1]["iou_loss"].item() > comp["iou_loss"].item() + 0.2


def test_boxes_are_square_padded_and_whole_image_when_empty() -> None:
    x = torch.zeros(2, 256, 256)
    x[0, 100:120, 50:150] = 1
    boxes = square_boxes(x, 0.5, pad=5.0)
    x0, y0, x1, y1 = boxes[0].tolist()
    assert x1 - x0 == pytest.approx(y1 - y0) == pytest.approx(100 + 10)
    assert ((x0 + x1) / 2, (y0 + y1) / 2) == pytest.approx((100, 110))
    assert boxes[1].tolist() == [0, 0, 256, 256]
    assert as_image_batch(np.zeros((3, 1, 8, 8))).shape == (3, 8, 8)
    with pytest.raises(ValueError):
        as_image_batch(torch.zeros(2, 3, 8, 8))


def test_prediction_box_uses_threshold_but_crop_keeps_soft_values() -> None:
    x = torch.zeros(1, 64, 64)
    x[0, 20:40, 20:40] = 0.9
    x[0, 0:5, 0:5] = 0.3  # below 0.5: outside the box
    crops, boxes = align(x, size=32, pad=0.0)
    assert boxes[0].tolist() == [20, 20, 40, 40]
    assert crops.max().item() == pytest.approx(0.9, abs=1e-5)


def test_gradients_reach_the_pixels_through_every_term(clip) -> None:
    t = _shape()
    m = torch.from_numpy(find_holes(t.numpy().astype(np.uint8))).float()
    m[40:60, 20:40] = 1  # the bar's neighbourhood is expressive too
    loss = ImageLoss(t, CFG, clip=clip, expressive=m)
    g = torch.Generator().manual_seed(0)
    pred = (0.6 * torch.roll(t, (2, 3), (0, 1)) + 0.3 * torch.rand(64, 64, generator=g))[None, None]
    pred.requires_grad_(True)
    theta = torch.zeros(1, 21, requires_grad=True)
    _, comp = loss(pred, theta=theta, theta_prev=torch.full((21,), 0.1))
    for name in ("mae", "iou_loss", "clip", "exp_iou", "exp_clip", "total"):
        (grad,) = torch.autograd.grad(comp[name].sum(), pred, retain_graph=True)
        assert torch.isfinite(grad).all() and grad.abs().sum().item() > 1e-6, name
    (grad,) = torch.autograd.grad(comp["temporal"].sum(), theta, retain_graph=True)
    assert grad.abs().sum().item() > 0
    assert torch.autograd.grad(comp["total"].sum(), theta)[0].abs().sum().item() > 0


def test_clip_term_with_small_random_model(clip) -> None:
    t = _shape()
    loss = ImageLoss(t, CFG, clip=clip)
    other = torch.zeros(64, 64)
    other[5:60, 30:36] = 1
    _, comp = loss(torch.stack([t, other]))
    assert comp["clip"][0].item() == pytest.approx(0.0, abs=1e-5)
    assert 0.0 < comp["clip"][1].item() <= 2.0
    base = CFG.w_mae * comp["mae"] + CFG.w_iou * comp["iou_loss"] + CFG.w_clip * comp["clip"]
    torch.testing.assert_close(comp["base"], base)
    white = clip.preprocess(torch.zeros(1, 16, 16))  # no shadow → a white image in display convention
    torch.testing.assert_close(white, ((1 - clip.mean) / clip.std).expand(1, 3, 32, 32))
    emb = clip(torch.rand(3, 1, 40, 40))
    assert emb.shape == (3, TINY_CLIP_CFG["embed_dim"])
    torch.testing.assert_close(emb.norm(dim=1), torch.ones(3))
    assert not any(p.requires_grad for p in clip.parameters())


def test_masked_terms_look_only_inside_the_region(clip) -> None:
    t = torch.zeros(64, 64)
    t[10:54, 10:54] = 1
    t[24:40, 24:40] = 0  # an opening: the expressive region
    m = torch.from_numpy(find_holes(t.numpy().astype(np.uint8))).float()
    loss = ImageLoss(t, CFG, clip=clip, expressive=m)
    outside = t.clone()
    outside[12:20, 12:20] = 0  # a change away from the opening (the box stays)
    closed = t.clone()
    closed[24:40, 24:40] = 1  # the opening filled
    _, comp = loss(torch.stack([outside, closed]))
    assert comp["iou_loss"][0].item() > 0.01
    assert comp["exp_iou"][0].item() == pytest.approx(0.0, abs=1e-5)
    assert comp["exp_clip"][0].item() == pytest.approx(0.0, abs=1e-5)
    assert comp["exp_iou"][1].item() > 0.9  # not exactly 1: the resampled region has soft edges
    assert comp["exp_clip"][1].item() > 0.0
    expr = CFG.w_exp_iou * comp["exp_iou"] + CFG.w_exp_clip * comp["exp_clip"]
    torch.testing.assert_close(comp["expr"], expr)
    torch.testing.assert_close(comp["total"], comp["base"] + comp["expr"])


def test_without_clip_or_region_terms_are_nan_and_left_out() -> None:
    t = _shape()
    cfg = LossConfig(crop_size=64, use_clip=False)
    total, comp = ImageLoss(t, cfg)(torch.roll(t, 1, 0)[None])
    for name in ("clip", "exp_clip", "exp_iou", "expr", "temporal"):
        assert math.isnan(comp[name].item()), name
    assert torch.isfinite(total).all()
    torch.testing.assert_close(total, cfg.w_mae * comp["mae"] + cfg.w_iou * comp["iou_loss"])
    with pytest.raises(StudioError, match="use_clip=False"):
        ImageLoss(t, LossConfig())  # CLIP asked for, no model given


def test_one_target_per_sample_and_bad_inputs(clip) -> None:
    a, b = _shape(), torch.zeros(64, 64)
    b[10:50, 28:36] = 1
    loss = ImageLoss(torch.stack([a, b]), CFG, clip=clip)
    same = loss(torch.stack([a, b]))[0]
    swapped = loss(torch.stack([b, a]))[0]
    assert same.abs().max().item() < 1e-5 and (swapped > 0.05).all()
    with pytest.raises(ValueError):
        loss(torch.stack([a, b, a]))
    with pytest.raises(StudioError, match="no shadow"):
        ImageLoss(torch.zeros(64, 64), CFG, clip=clip)
    with pytest.raises(ValueError):
        ImageLoss(a, CFG, clip=clip, expressive=torch.zeros(32, 32))


def test_real_target_matches_itself_across_resolutions(shared_targets: Path) -> None:
    """The ASL "o" at 400² against its own 128² framing: alignment makes them agree."""
    full = load_target(shared_targets / "asl" / "o" / "hand1_o_bot_seg_1_cropped.jpeg")
    small = square_frame(full, 128, shadow_box(full), margin=0.1)
    loss = ImageLoss(full, LossConfig(crop_size=64, use_clip=False), expressive=find_holes(full))
    comp = loss(small[None])[1]
    assert comp["iou_loss"].item() < 0.04 and comp["exp_iou"].item() < 0.5  # the small opening is edge-sensitive
    assert ImageLoss(small, LossConfig(crop_size=64, use_clip=False))(np.rot90(small).copy()[None])[0].item() > 0.1


def test_load_clip_never_downloads_and_says_what_to_do(tmp_path: Path) -> None:
    with pytest.raises(ClipWeightsError) as err:
        load_clip("ViT-B-32", cache_dir=tmp_path)
    msg = str(err.value)
    assert "open_clip_model.safetensors" in msg and "never downloaded" in msg
    assert not re.search(r"(^|\s)--[a-z]", msg)  # no face's words (a flag); the hub's folder names have "--"
    assert str(tmp_path) in msg
    with pytest.raises(ClipWeightsError, match="not found: .*nope.pt"):
        load_clip("ViT-B-32", weights=tmp_path / "nope.pt")
    with pytest.raises(ClipWeightsError, match="unknown open_clip model"):
        load_clip("no-such-model")


def test_the_default_clips_sources_are_open_clips_own_and_looking_needs_no_open_clip(tmp_path: Path) -> None:
    """``KNOWN_SOURCES`` (the fast path) says what open_clip's pretrained table says, and a run without local
    weights learns that CLIP is off without importing open_clip or torchvision (a fresh interpreter)."""
    import open_clip

    assert KNOWN_SOURCES
    for (name, pretrained), known in KNOWN_SOURCES.items():
        cfg = open_clip.get_pretrained_cfg(name, pretrained)
        assert {key: cfg[key] for key in known} == known
    code = (
        "import sys; from studio.imitate.clip_loss import find_clip\n"
        "clip, line = find_clip(cache_dir=sys.argv[1])\n"
        "print(clip is None, 'open_clip' in sys.modules, 'torchvision' in sys.modules, line)"
    )
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.startswith("True False False CLIP terms off: no local ViT-B-32 weights"), done.stdout


def test_cache_lookup_finds_url_and_hub_files(tmp_path: Path) -> None:
    assert cache_candidates("ViT-B-32", "openai", tmp_path) == [tmp_path / "ViT-B-32.pt"]
    snap = tmp_path / "models--timm--vit_base_patch32_clip_224.openai" / "snapshots" / "abc123"
    snap.mkdir(parents=True)
    (snap / "open_clip_model.safetensors").write_bytes(b"x")
    (tmp_path / "models--timm--vit_base_patch32_clip_224.openai" / "refs").mkdir()
    (tmp_path / "models--timm--vit_base_patch32_clip_224.openai" / "refs" / "main").write_text("abc123")
    found = cache_candidates("ViT-B-32", "openai", tmp_path)
    assert found[0] == snap / "open_clip_model.safetensors"


@pytest.fixture(scope="module")
def tiny_model_name(tmp_path_factory) -> str:
    """Register the tiny config with open_clip under a model name, as a user's config file would be."""
    import open_clip

    path = tmp_path_factory.mktemp("clipcfg") / "shadow-test-tiny.json"
    path.write_text(json.dumps(TINY_CLIP_CFG))
    open_clip.add_model_config(path)
    return "shadow-test-tiny"


def _tiny_model(seed: int):
    from open_clip.model import CLIP, CLIPTextCfg, CLIPVisionCfg

    torch.manual_seed(seed)
    c = TINY_CLIP_CFG
    return CLIP(c["embed_dim"], CLIPVisionCfg(**c["vision_cfg"]), CLIPTextCfg(**c["text_cfg"]))


@pytest.mark.filterwarnings("ignore")
def test_load_clip_from_checkpoint_files(tmp_path: Path, tiny_model_name: str) -> None:
    model = _tiny_model(7)
    x = torch.rand(2, 48, 48)
    expected = tiny_clip(seed=7)(x)
    state = tmp_path / "tiny.pt"
    torch.save(model.state_dict(), state)
    torch.testing.assert_close(load_clip(tiny_model_name, weights=state)(x), expected)
    script = tmp_path / "tiny_jit.pt"  # OpenAI's checkpoints are TorchScript archives
    torch.jit.save(torch.jit.trace_module(model, {"encode_image": (torch.rand(1, 3, 32, 32),)}), script)
    torch.testing.assert_close(load_clip(tiny_model_name, weights=script)(x), expected)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a checkpoint")
    with pytest.raises(ClipWeightsError, match="cannot load CLIP weights"):
        load_clip(tiny_model_name, weights=junk)


def test_one_clip_rule_on_every_face(tmp_path: Path, monkeypatch) -> None:
    """Off unless weights are given or cached (never an error then), on with given weights, off when asked; one line
    says which. The command line's flags reach the same rule."""
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hub"))  # an empty cache: nothing is found
    clip, line = find_clip(cache_dir=tmp_path)
    assert clip is None and "off" in line and "never downloaded" in line
    clip, line = find_clip(enabled=False)
    assert clip is None and "off" in line
    with pytest.raises(ClipWeightsError, match="not found"):
        find_clip(tmp_path / "w.safetensors")
    parser = argparse.ArgumentParser()
    add_clip_arguments(parser)
    assert clip_from_args(parser.parse_args(["--no-clip"])) is None
    with pytest.raises(ClipWeightsError, match="not found"):
        clip_from_args(parser.parse_args(["--clip-weights", str(tmp_path / "w.safetensors")]))
