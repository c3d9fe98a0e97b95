"""FK: numpy, compiled and torch paths against PyBullet's link poses (the slow reference)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from studio.sim.kinematics import TorchFK, fk_numpy
from studio.sim.sampling import sample_poses
from studio.sim.shadow import ShadowRenderer


@pytest.fixture(scope="module")
def poses(hand):
    return sample_poses(hand, 30, np.random.default_rng(7))[0]


def pybullet_link_poses(hand, theta: np.ndarray) -> np.ndarray:
    """(B, L, 4, 4) from PyBullet's own FK (link frames = URDF link frames, inertia at the link origin)."""
    import pybullet as p

    cid = p.connect(p.DIRECT)
    try:
        body = p.loadURDF(str(hand.urdf_path), useFixedBase=True, physicsClientId=cid)
        out = np.tile(np.eye(4), (len(theta), len(hand.link_names), 1, 1))
        for b, q in enumerate(theta):
            for i, v in enumerate(q):
                p.resetJointState(body, i, float(v), physicsClientId=cid)
            for i in range(hand.dof):
                s = p.getLinkState(body, i, computeForwardKinematics=True, physicsClientId=cid)
                out[b, i + 1, :3, :3] = np.array(p.getMatrixFromQuaternion(s[5])).reshape(3, 3)
                out[b, i + 1, :3, 3] = s[4]
        return out
    finally:
        p.disconnect(cid)


def test_numpy_fk_matches_pybullet(hand, poses):
    ref = pybullet_link_poses(hand, poses)
    ours = fk_numpy(hand, poses)
    assert np.abs(ours[..., :3, 3] - ref[..., :3, 3]).max() <= 1e-5
    assert np.abs(ours[..., :3, :3] - ref[..., :3, :3]).max() <= 1e-5


def test_compiled_fk_matches_numpy(hand, poses):
    assert np.allclose(ShadowRenderer(hand).fk(poses), fk_numpy(hand, poses), atol=1e-12)


def test_torch_fk_matches_pybullet_and_is_differentiable(hand, poses):
    fk = TorchFK(hand, device="cpu", dtype=torch.float64)
    theta = torch.tensor(poses, requires_grad=True)
    T = fk.fk(theta)
    assert T.shape == (len(poses), 22, 4, 4)
    ref = pybullet_link_poses(hand, poses)
    assert np.abs(T.detach().numpy()[..., :3, 3] - ref[..., :3, 3]).max() <= 1e-5
    frames = fk.joint_frames(theta)
    assert frames.shape == (len(poses), 21, 4, 4)
    frames[..., :3, 3].sum().backward()
    assert theta.grad is not None and torch.isfinite(theta.grad).all() and theta.grad.abs().sum() > 0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
def test_torch_fk_cuda_matches_cpu(hand, poses):
    cpu = TorchFK(hand, device="cpu").fk(torch.tensor(poses, dtype=torch.float32))
    gpu = TorchFK(hand, device="cuda").fk(torch.tensor(poses, dtype=torch.float32)).cpu()
    assert torch.allclose(cpu, gpu, atol=1e-5)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_fk_composition_law(hand, seed):
    """T_world_child = T_world_parent · T_parent_joint · Rot(axis, q) for every joint, and rotations stay rigid."""
    from studio.sim.kinematics import axis_angle_matrices

    theta = sample_poses(hand, 1, np.random.default_rng(seed))[0]
    T = fk_numpy(hand, theta)[0]
    index = {n: i for i, n in enumerate(hand.link_names)}
    for j, joint in enumerate(hand.joints):
        R = np.eye(4)
        R[:3, :3] = axis_angle_matrices(joint.axis, theta[0, j : j + 1])[0]
        expect = T[index[joint.parent]] @ joint.T_parent_joint @ R
        assert np.allclose(T[index[joint.child]], expect, atol=1e-12)
    Rs = T[:, :3, :3]
    assert np.allclose(Rs @ Rs.transpose(0, 2, 1), np.eye(3), atol=1e-10)
    assert np.allclose(np.linalg.det(Rs), 1.0)
