"""The fast shadow renderer against PyBullet's camera at the light, plus its own laws."""

from __future__ import annotations

import math
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


def _reference_outline(T_link, pieces, rig, M, p):
    """Pixel (u, v) points of piece ``p``'s shadow, in the kernel's order and arithmetic (plain Python floats)."""
    (Lx, Ly, Lz), zb, half = rig.light, float(rig.backdrop_z), rig.window / 2
    scale = rig.resolution / (2.0 * half)
    ring_k = math.sqrt(2 * math.pi / (M * math.sin(2 * math.pi / M)))
    Tl, r, pts = T_link[pieces.link[p]].tolist(), float(pieces.radius[p]), []
    for q in range(pieces.count[p]):
        lx, ly, lz = pieces.points[p, q].tolist()
        cx, cy, cz = (Tl[a][0] * lx + Tl[a][1] * ly + Tl[a][2] * lz + Tl[a][3] for a in range(3))
        if r <= 0.0:
            s = (Lz - zb) / (Lz - cz)
            pts.append((((Lx + s * (cx - Lx)) + half) * scale, (half - (Ly + s * (cy - Ly))) * scale))
            continue
        vx, vy, vz = cx - Lx, cy - Ly, cz - Lz
        d = math.sqrt(vx * vx + vy * vy + vz * vz)
        ux, uy, uz = vx / d, vy / d, vz / d
        ox, oy, oz = cx - ux * r * r / d, cy - uy * r * r / d, cz - uz * r * r / d
        rho = r * math.sqrt(max(d * d - r * r, 0.0)) / d * ring_k
        ax, ay, az = (1.0, 0.0, 0.0) if abs(ux) < 0.9 else (0.0, 1.0, 0.0)
        e1x, e1y, e1z = uy * az - uz * ay, uz * ax - ux * az, ux * ay - uy * ax
        nn = math.sqrt(e1x * e1x + e1y * e1y + e1z * e1z)
        e1x, e1y, e1z = e1x / nn, e1y / nn, e1z / nn
        e2x, e2y, e2z = uy * e1z - uz * e1y, uz * e1x - ux * e1z, ux * e1y - uy * e1x
        for m in range(M):
            ca, sa = math.cos(2.0 * math.pi * m / M) * rho, math.sin(2.0 * math.pi * m / M) * rho
            wx, wy, wz = ox + ca * e1x + sa * e2x, oy + ca * e1y + sa * e2y, oz + ca * e1z + sa * e2z
            s = (Lz - zb) / (Lz - wz)
            pts.append((((Lx + s * (wx - Lx)) + half) * scale, (half - (Ly + s * (wy - Ly))) * scale))
    return pts


def _reference_hull(pts):
    """Andrew's monotone chain (collinear points dropped), counter-clockwise."""
    pts = sorted(pts)

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    hull = []
    for q in pts:  # lower chain
        while len(hull) >= 2 and cross(hull[-2], hull[-1], q) <= 0:
            hull.pop()
        hull.append(q)
    lower = len(hull)
    for q in pts[-2::-1]:  # upper chain, never popping into the lower one
        while len(hull) > lower and cross(hull[-2], hull[-1], q) <= 0:
            hull.pop()
        hull.append(q)
    return hull[:-1] if len(hull) > 1 else hull


def _reference_fill(img, hull):
    """Set the pixels whose centres lie in the convex polygon: per row, the span between its edges' crossings."""
    H, W = img.shape
    k = len(hull)
    if k < 3:
        return
    vs = [v for _, v in hull]
    i0, i1 = max(0, math.ceil(min(vs) - 0.5)), min(H - 1, math.floor(max(vs) - 0.5))
    lo_u, hi_u = {}, {}
    for e in range(k):
        (ax, ay), (bx, by) = hull[e], hull[(e + 1) % k]
        if ay == by:
            continue
        for i in range(max(i0, math.ceil(min(ay, by) - 0.5)), min(i1, math.floor(max(ay, by) - 0.5)) + 1):
            u = ax + (bx - ax) * (i + 0.5 - ay) / (by - ay)
            lo_u[i], hi_u[i] = min(lo_u.get(i, 1e30), u), max(hi_u.get(i, -1e30), u)
    for i in lo_u:
        j0, j1 = max(0, math.ceil(lo_u[i] - 0.5)), min(W - 1, math.floor(hi_u[i] - 0.5))
        if j1 >= j0:
            img[i, j0 : j1 + 1] = 1


def reference_render(renderer, theta):
    """Slow pure-Python twin of the compiled kernel (sort + monotone chain + per-edge scanline), ``(B, H, W)``."""
    rig, pieces, M = renderer.rig, renderer.pieces, renderer.ring_points
    out = np.zeros((len(theta), rig.resolution, rig.resolution), np.uint8)
    for b, T_link in enumerate(renderer.fk(theta)):
        for p in range(len(pieces.link)):
            _reference_fill(out[b], _reference_hull(_reference_outline(T_link, pieces, rig, M, p)))
    return out


@pytest.mark.slow
@pytest.mark.parametrize("res, ring_points, n", [(64, 16, 300), (128, 16, 300), (64, 7, 60), (96, 24, 60)])
def test_kernel_equals_slow_reference_bit_for_bit(hand, res, ring_points, n):
    """The kernel's O(M) ring merges, inlined hull and span fill give exactly the reference's pixels."""
    r = ShadowRenderer(hand, Rig(resolution=res), ring_points=ring_points)
    poses = sample_poses(hand, n, np.random.default_rng(res + ring_points))[0]
    ref = reference_render(r, poses)
    assert ref.any(axis=(1, 2)).all()
    batch = r.render(poses, check=False)  # threaded kernel (n >= 64) or serial
    head = r.render(poses[:9], check=False)  # serial kernel
    assert np.array_equal(batch, ref), f"{int((batch != ref).sum())} pixels differ"
    assert np.array_equal(head, ref[:9])


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


@pytest.mark.parametrize(
    "rig",
    [
        Rig(light=(0.0, 0.0, 2.7), backdrop_z=-1.15, hand_offset=(0.02, -0.015, 0.05), roll=0.07, foam=0.003),
        Rig(hand_offset=(-0.03, 0.0, 0.0), foam=-0.002),
    ],
    ids=["moved-rolled-thicker", "shifted-thinner"],
)
def test_a_calibrated_rig_matches_the_pybullet_reference(hand, rig):
    """A moved, rolled mount and a thicker or thinner shell, rendered by the kernel and by PyBullet's camera
    (its URDF loaded at the mount's pose, its pieces grown by the foam)."""
    rig = rig.with_resolution(128)
    poses = sample_poses(hand, 12, np.random.default_rng(31))[0]
    ours = ShadowRenderer(hand, rig).render(poses)
    with PyBulletShadowCamera(hand, rig) as cam:
        ref = np.stack([cam.render(q) for q in poses])
    scores = iou(ours, ref)
    assert scores.mean() >= 0.96 and scores.min() >= 0.9, scores
    assert abs(ours.sum() / ref.sum() - 1) < 0.04
    nominal = ShadowRenderer(hand, Rig(resolution=128)).render(poses)
    assert iou(ours, nominal).mean() < 0.9  # the calibration's changes are visible


def test_foam_grows_the_shadow_and_the_offset_moves_it(hand):
    poses = sample_poses(hand, 6, np.random.default_rng(8))[0]
    base = ShadowRenderer(hand, Rig(resolution=256)).render(poses)
    fat = ShadowRenderer(hand, Rig(resolution=256, foam=0.004)).render(poses)
    assert (fat >= base).all() and fat.sum() > 1.1 * base.sum()
    moved = ShadowRenderer(hand, Rig(resolution=256, hand_offset=(0.03, 0.0, 0.0))).render(poses)
    cols = np.arange(256)
    shift_px = (moved.sum(1) @ cols / moved.sum((1, 2)) - base.sum(1) @ cols / base.sum((1, 2))).mean()
    expected = 0.03 * 4 / 3 / Rig().pixel_size  # x moves by s·dx on the backdrop, s ≈ 4/3 near the palm
    assert shift_px == pytest.approx(expected, rel=0.1)


def test_the_paper_rig_keeps_its_record_and_a_calibrated_one_round_trips():
    assert Rig().to_dict() == {"light": [0.0, 0.0, 3.0], "backdrop_z": -1.0, "window": 0.6, "resolution": 256}
    rig = Rig(light=(0.0, 0.0, 2.8), hand_offset=(0.01, 0.0, -0.02), foam=0.001, roll=0.1)
    assert Rig.from_dict(rig.to_dict()) == rig and rig.hash != Rig().hash
    with pytest.raises(ValueError, match="between the light and the backdrop"):
        Rig(hand_offset=(0.0, 0.0, 3.5))


TWINS = """
import numpy as np
from studio.sim import raster
parent = np.array([-1, 0, 1], np.int64)
T_origin = np.tile(np.eye(4), (3, 1, 1))
axis = np.tile([0.0, 0.0, 1.0], (3, 1))
theta = np.zeros((4, 3))
raster.fk_batch_serial(theta, parent, T_origin, axis)  # the serial kernel first, as small batches come first
raster.fk_batch(theta, parent, T_origin, axis)
for kernel in (raster.fk_batch_serial, raster.fk_batch):
    (sig,) = kernel.signatures
    compiled = not kernel.stats.cache_hits
    threaded = "do_scheduling" in kernel.inspect_llvm(sig) if compiled else None
    print(kernel.py_func.__name__, compiled, threaded)
"""


def test_the_threaded_and_serial_kernels_keep_their_own_compiled_code(tmp_path):
    """numba keys its disk cache by a function's name, not its options (numba#6845): the threaded twin compiled
    after the serial one must compile its own threaded code, not load the serial one's (it ran large batches on
    one core)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"))
    out = subprocess.run([sys.executable, "-c", TWINS], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split("\n")[:2] == ["_fk_batch_serial True False", "_fk_batch True True"], out.stdout
