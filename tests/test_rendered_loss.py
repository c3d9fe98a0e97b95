"""studio.imitate.rendered_loss: the compiled loss of rendered shadows against ImageLoss (the torch reference)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from studio.imitate.config import COMPONENTS, LossConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.rendered_loss import PARALLEL_FROM, RenderedLoss, crop_batch, fast_loss
from studio.sim.crop import align, pad_pixels
from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer
from studio.targets.holes import find_holes


@pytest.fixture(scope="module")
def shadows(hand) -> np.ndarray:
    """Rendered shadows (40, 96, 96) of random poses, two of them empty or cut by the frame edge."""
    poses = sample_poses(hand, 38, np.random.default_rng(7))[0]
    s = ShadowRenderer(hand, Rig(resolution=96)).render(poses)
    empty = np.zeros((1, 96, 96), np.uint8)
    edge = np.zeros((1, 96, 96), np.uint8)
    edge[0, 60:, 70:] = 1  # touches the bottom-right border
    return np.concatenate([s, empty, edge])


@pytest.mark.parametrize("size", [96, 48, 40])
def test_crop_matches_align(shadows, size) -> None:
    ref, _ = align(torch.from_numpy(shadows).float(), size, 5.0, 0.5)
    ours = crop_batch(shadows, pad_pixels(5.0, 96, 96), size)
    assert ours.shape == (len(shadows), size, size) and ours.dtype == np.float32
    np.testing.assert_allclose(ours, ref.numpy(), atol=2e-6)


@pytest.mark.parametrize("size,expressive,prev", [(96, False, False), (48, True, False), (64, True, True)])
def test_loss_matches_image_loss(shadows, size, expressive, prev) -> None:
    target = shadows[3]
    holes = find_holes(target) if expressive else None
    if expressive and not holes.any():  # a hand-made opening so the expressive term is exercised
        holes = np.zeros_like(target)
        holes[40:50, 40:50] = 1
    ref = ImageLoss(target, LossConfig(use_clip=False, crop_size=size), expressive=holes)
    fast = RenderedLoss(ref)
    rng = np.random.default_rng(0)
    theta = rng.normal(0, 0.3, (len(shadows), 21)) if prev else None
    theta_prev = rng.normal(0, 0.3, 21) if prev else None
    total, comps = fast(shadows, theta, theta_prev)
    args = (torch.from_numpy(theta), torch.from_numpy(theta_prev)) if prev else ()
    r_total, r_comps = ref(torch.from_numpy(shadows).float(), *args)
    assert set(comps) == set(COMPONENTS)
    np.testing.assert_allclose(total, r_total.double().numpy(), atol=3e-6)
    for k in COMPONENTS:
        np.testing.assert_allclose(comps[k], r_comps[k].double().numpy(), atol=3e-6, err_msg=k)
    assert np.isnan(comps["clip"]).all()
    assert np.isnan(comps["temporal"]).all() != prev
    assert np.isnan(comps["exp_iou"]).all() != expressive
    if not prev:
        assert total[3] == pytest.approx(0.0, abs=1e-6)  # the target scores itself 0


def test_threaded_kernel_agrees_with_serial(hand) -> None:
    poses = sample_poses(hand, PARALLEL_FROM, np.random.default_rng(1))[0]
    s = ShadowRenderer(hand, Rig(resolution=64)).render(poses)
    fast = RenderedLoss(ImageLoss(s[0], LossConfig(use_clip=False, crop_size=64)))
    big, _ = fast(s)
    small = np.concatenate([fast(s[i : i + 16])[0] for i in range(0, len(s), 16)])
    np.testing.assert_array_equal(big, small)


def test_fast_loss_declines_what_it_cannot_do(shadows) -> None:
    two = ImageLoss(shadows[:2], LossConfig(use_clip=False, crop_size=48))
    assert fast_loss(two) is None
    with pytest.raises(ValueError, match="one target without CLIP"):
        RenderedLoss(two)
    assert isinstance(fast_loss(ImageLoss(shadows[0], LossConfig(use_clip=False, crop_size=48))), RenderedLoss)
