"""The rig fit (studio.learn.rig_fit) and the rig as people write it (studio.sim.rig_file)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studio.learn.rig_fit import (
    RigFitConfig,
    RigFitError,
    block_mean,
    calibration_poses,
    coverage,
    fit_rig,
    window_iou_loss,
)
from studio.sim.hand import load_hand
from studio.sim.physics import CollisionWorld
from studio.sim.rig_file import RigFileError, read_rig_file, rig_from_mapping, rig_to_mapping
from studio.sim.shadow import Rig, ShadowRenderer


@pytest.fixture(scope="module")
def hand():
    return load_hand()


@pytest.fixture(scope="module")
def poses(hand):
    return calibration_poses(hand, 8)


def test_calibration_poses_are_collision_free_distinct_and_repeatable(hand, poses):
    with CollisionWorld(hand) as world:
        assert not world.in_collision(poses).any()
    assert np.array_equal(poses, calibration_poses(hand, 8))
    gaps = np.linalg.norm(poses[:, None] - poses[None], axis=-1)[np.triu_indices(8, 1)]
    assert gaps.min() > 0.5  # rad: no two alike


@pytest.mark.parametrize("k", [1, 2, 3, 4])
def test_block_mean_is_the_mean_of_each_block(k):
    """The strided additions against numpy's mean over the blocks' axes: the same numbers, exactly for shadows (sums
    of 0s and 1s), to float32 rounding for coverage."""
    rng = np.random.default_rng(k)
    binary = (rng.random((3, 40 * k, 40 * k)) < 0.4).astype(np.float32)
    assert np.array_equal(block_mean(binary, k), binary.reshape(3, 40, k, 40, k).mean(axis=(2, 4)))
    soft = rng.random((2, 24 * k, 24 * k)).astype(np.float32)
    got = block_mean(soft, k)
    assert got.shape == (2, 24, 24) and got.dtype == np.float32
    np.testing.assert_allclose(got, soft.reshape(2, 24, k, 24, k).mean(axis=(2, 4)), rtol=0, atol=1e-6)


def _captured(hand, rig, theta, noise=0.08, seed=1):
    """What a camera would give: the true rig's shadows as coverage (drawn 4× finer), with pixel noise."""
    cov = coverage(ShadowRenderer(hand, rig.with_resolution(4 * 128)), theta, 4)
    return np.clip(cov + np.random.default_rng(seed).normal(0, noise, cov.shape), 0, 1)


@pytest.mark.slow
def test_the_fit_recovers_a_rig_set_up_otherwise(hand, poses):
    true = Rig(light=(0.0, 0.0, 2.75), backdrop_z=-1.1, hand_offset=(0.012, -0.01, 0.0), roll=math.radians(3),
               foam=0.0015)  # fmt: skip
    fit = fit_rig(poses, _captured(hand, true, poses), Rig(), RigFitConfig(max_evals=600))
    a = fit.after
    assert a.light[2] == pytest.approx(2.75, rel=0.03)
    assert math.degrees(a.roll) == pytest.approx(3, abs=0.3)
    assert a.foam == pytest.approx(0.0015, abs=0.0005)
    assert a.hand_offset[:2] == pytest.approx((0.012, -0.01), abs=0.002)
    assert fit.loss_after < 0.5 * fit.loss_before
    assert len(fit.per_pose_after) == len(poses)


def test_the_fit_holds_what_it_is_not_asked_to_move(hand, poses):
    true = Rig(roll=math.radians(-2))
    fit = fit_rig(poses[:4], _captured(hand, true, poses[:4]), Rig(light=(0.0, 0.0, 2.9)),
                  RigFitConfig(fit=("roll",), max_evals=80, supersample=2))  # fmt: skip
    assert fit.after.light[2] == 2.9 and fit.after.foam == 0
    assert math.degrees(fit.after.roll) == pytest.approx(-2, abs=0.5)


def test_bad_captures_are_refused_in_words(hand, poses):
    with pytest.raises(RigFitError, match="one square capture per pose"):
        fit_rig(poses, np.zeros((3, 64, 64)), Rig())
    with pytest.raises(RigFitError, match="every capture is empty"):
        fit_rig(poses[:2], np.zeros((2, 64, 64)), Rig())
    with pytest.raises(ValueError, match="unknown rig parameter"):
        RigFitConfig(fit=("light", "roll"))


def test_window_iou_loss():
    a = np.zeros((8, 8))
    a[2:6, 2:6] = 1
    b = np.roll(a, 2, axis=1)
    assert window_iou_loss(a, a) == 0
    assert window_iou_loss(a, b) == pytest.approx(1 - 8 / 24)
    assert window_iou_loss(np.zeros((8, 8)), np.zeros((8, 8))) == 0


def test_the_rig_file_reads_the_issue_keys_and_round_trips(tmp_path):
    path = tmp_path / "rig.yaml"
    path.write_text("light_distance_m: 2.7\nbackdrop_distance_m: 1.2\nhand_offset_m: [0.01, 0, -0.02]\n"
                    "mount_roll_deg: 4\nfoam_mm: 1.5\ncamera: {fov_deg: 50}\n")  # fmt: skip
    rig, camera = read_rig_file(path)
    assert rig.light == (0.0, 0.0, 2.7) and rig.backdrop_z == -1.2 and rig.hand_offset == (0.01, 0.0, -0.02)
    assert math.degrees(rig.roll) == pytest.approx(4) and rig.foam == pytest.approx(0.0015)
    assert camera == {"fov_deg": 50}
    assert rig_to_mapping(rig_from_mapping(rig_to_mapping(rig))) == rig_to_mapping(rig)
    partial = tmp_path / "partial.yaml"
    partial.write_text("foam_mm: 2\n")
    assert read_rig_file(partial)[0] == Rig(foam=0.002)  # the rest nominal


@pytest.mark.parametrize(
    "text, message",
    [
        ("light_distance: 2.7\n", "unknown key"),
        ("light_distance_m: far\n", "must be a number"),
        ("hand_offset_m: [0, 1]\n", r"\[x, y, z\]"),
        ("light_distance_m: 0.5\nbackdrop_distance_m: 1\nhand_offset_m: [0, 0, 0.6]\n", "between the light"),
        ("camera: 3\n", "camera must be a mapping"),
        ("[1, 2\n", "not valid YAML"),
    ],
)
def test_a_bad_rig_file_is_one_clear_line(tmp_path, text, message):
    path = tmp_path / "rig.yaml"
    path.write_text(text)
    with pytest.raises(RigFileError, match=message):
        read_rig_file(path)
    with pytest.raises(RigFileError, match="not found"):
        read_rig_file(tmp_path / "missing.yaml")
