"""The fast shadow renderer against PyBullet's camera at the light, plus its own laws."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer, iou
from studio.sim.shadow_reference import PyBulletShadowCamera


@pytest.fixture(scope="module")
def renderer(hand):
    return ShadowRenderer(hand, Rig())


def test_matches_pybullet_camera_reference(hand, renderer):
    poses = sample_poses(hand, 24, np.random.default_rng(2024))[0]
    ours = renderer.render(poses)
    with PyBulletShadowCamera(hand, renderer.rig) as cam:
        ref = np.stack([cam.render(q) for q in poses])
    scores = iou(ours, ref)
    assert scores.mean() >= 0.97, scores
    assert scores.min() >= 0.93, scores
    # neither renderer is systematically fatter: the areas agree within 3 %
    assert abs(ours.sum() / ref.sum() - 1) < 0.03


def test_batched_equals_single(hand, renderer):
    poses = sample_poses(hand, 9, np.random.default_rng(5))[0]
    batch = renderer.render(poses)
    for b, q in enumerate(poses):
        assert np.array_equal(batch[b], renderer.render_one(q))


def test_output_convention(hand, renderer):
    img = renderer.render_one(hand.rest_pose())
    assert img.dtype == np.uint8 and img.shape == (256, 256)
    assert set(np.unique(img)) == {0, 1}
    # the open hand stands upright: fingers in the upper half, wrist stub in the lower half
    rows = np.flatnonzero(img.any(1))
    assert rows.min() < 40 and rows.max() > 140
    # the thumb is on the audience's right (+x): more shadow right of the centre column than left
    assert img[:, 128:].sum() > img[:, :128].sum()


def test_shadow_grows_as_hand_nears_light(hand):
    theta = hand.rest_pose()
    areas = []
    for light_z in (6.0, 4.0, 3.0, 2.0, 1.5):
        r = ShadowRenderer(hand, Rig(light=(0.0, 0.0, light_z), window=1.2))
        areas.append(int(r.render_one(theta).sum()))
    assert all(a < b for a, b in zip(areas, areas[1:])), areas
    # the hand is nearly planar at z ≈ 0: area scales with s² = ((Lz+1)/Lz)² within a few %
    s2 = [((z + 1) / z) ** 2 for z in (6.0, 1.5)]
    assert areas[-1] / areas[0] == pytest.approx(s2[1] / s2[0], rel=0.05)


def test_point_projection_matches_design_formula():
    rig = Rig()
    p = np.array([[0.1, -0.05, 0.0], [0.0, 0.2, 1.0]])
    xy = rig.project(p)
    assert np.allclose(xy[0], [0.1 * 4 / 3, -0.05 * 4 / 3])
    assert np.allclose(xy[1], [0.0, 0.2 * 4 / 2])


def test_whole_hand_fits_window(hand, renderer):
    poses = sample_poses(hand, 2000, np.random.default_rng(11))[0]
    imgs = renderer.render(poses, check=False)
    border = imgs[:, 0].any(1) | imgs[:, -1].any(1) | imgs[:, :, 0].any(1) | imgs[:, :, -1].any(1)
    assert not border.any(), f"{border.sum()} of 2000 shadows touch the window edge"


@pytest.mark.parametrize(
    "bad, message",
    [(np.zeros(7), "shape"), (np.full((2, 21), np.inf), "NaN"), (np.full(21, -2.0), "outside its limits")],
)
def test_bad_poses_raise(renderer, bad, message):
    with pytest.raises(ValueError, match=message):
        renderer.render(bad)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), res=st.sampled_from([32, 64, 85]))
def test_pixels_sample_the_continuous_shadow_at_their_centres(hand, seed, res):
    """Pixel j's centre at resolution r, (j + 0.5) / r, is pixel 3j+1's centre at 3r: the images must agree."""
    theta = sample_poses(hand, 1, np.random.default_rng(seed))[0]
    lo = ShadowRenderer(hand, Rig(resolution=res)).render(theta)[0]
    hi = ShadowRenderer(hand, Rig(resolution=3 * res)).render(theta)[0]
    mismatch = (lo != hi[1::3, 1::3]).sum()
    assert mismatch <= 1, f"{mismatch} pixels differ"  # allow one centre lying exactly on an edge (rounding)


def test_reference_camera_releases_client_and_folder(hand):
    import pybullet as p

    from studio.errors import ClosedError

    with PyBulletShadowCamera(hand, Rig(resolution=32)) as cam:
        client, folder = cam.client, Path(cam._tmp.name)
        assert p.isConnected(client) and any(folder.glob("*.obj"))
        assert cam.render(hand.rest_pose()).any()
    assert not p.isConnected(client) and not folder.exists()
    cam.close()  # closing twice is fine
    with pytest.raises(ClosedError, match="PyBulletShadowCamera was closed"):
        cam.render(hand.rest_pose())
