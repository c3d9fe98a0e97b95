"""Batched forward kinematics of the hand: a fast numpy path (renderer, collisions) and a differentiable
torch path (self-model input) built with pytorch_kinematics. Both are tested against PyBullet link poses.

Frames: ``T_world_link (B, L, 4, 4)`` with links in ``hand.link_names`` order (root first, then each joint's
child in joint order), world = palm-centre frame of the rig (DESIGN §1).
"""

from __future__ import annotations

import numpy as np

from studio.sim.hand import Hand


def axis_angle_matrices(axis: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Rotation matrices about a fixed unit ``axis (3,)`` by angles ``q (B,)``: (B, 3, 3) (Rodrigues)."""
    x, y, z = axis
    c, s = np.cos(q), np.sin(q)
    C = 1.0 - c
    R = np.empty(q.shape + (3, 3))
    R[..., 0, 0] = c + x * x * C
    R[..., 0, 1] = x * y * C - z * s
    R[..., 0, 2] = x * z * C + y * s
    R[..., 1, 0] = y * x * C + z * s
    R[..., 1, 1] = c + y * y * C
    R[..., 1, 2] = y * z * C - x * s
    R[..., 2, 0] = z * x * C - y * s
    R[..., 2, 1] = z * y * C + x * s
    R[..., 2, 2] = c + z * z * C
    return R


def fk_numpy(hand: Hand, theta: np.ndarray) -> np.ndarray:
    """``theta (B, 21)`` rad → ``T_world_link (B, L, 4, 4)`` float64. No limit checks (callers validate)."""
    theta = np.asarray(theta, dtype=np.float64)
    if theta.ndim == 1:
        theta = theta[None]
    B = theta.shape[0]
    index = {name: i for i, name in enumerate(hand.link_names)}
    T = np.empty((B, len(hand.link_names), 4, 4))
    T[:, 0] = np.eye(4)
    for j, joint in enumerate(hand.joints):
        T_parent = T[:, index[joint.parent]]
        T_joint = T_parent @ joint.T_parent_joint  # (B, 4, 4)
        R = axis_angle_matrices(joint.axis, theta[:, j])
        child = T[:, index[joint.child]]
        child[:, :3, :3] = T_joint[:, :3, :3] @ R
        child[:, :3, 3] = T_joint[:, :3, 3]
        child[:, 3] = (0.0, 0.0, 0.0, 1.0)
    return T


class TorchFK:
    """Differentiable batched FK on CPU or CUDA via pytorch_kinematics.

    ``fk(theta (B, 21)) -> T_world_link (B, L, 4, 4)``; ``joint_frames(theta) -> (B, 21, 4, 4)``: the pose of
    each joint's child link, the self-model's input.
    """

    def __init__(self, hand: Hand, device: str | None = None, dtype=None):
        import pytorch_kinematics as pk
        import torch

        self.hand = hand
        self.dtype = dtype or torch.float32
        self.device = torch.device(device or ("cuda" if torch.cuda.is_available() else "cpu"))
        chain = pk.build_chain_from_urdf(hand.urdf_text)
        names = chain.get_joint_parameter_names()
        if list(names) != hand.joint_names:
            raise ValueError(f"pytorch_kinematics joint order {names} differs from the URDF order")
        self.chain = chain.to(dtype=self.dtype, device=self.device)

    def fk(self, theta):
        """``theta (B, 21)`` tensor rad → ``T_world_link (B, L, 4, 4)`` tensor (differentiable)."""
        import torch

        theta = theta.to(device=self.device, dtype=self.dtype)
        if theta.ndim == 1:
            theta = theta[None]
        frames = self.chain.forward_kinematics(theta)
        B = theta.shape[0]
        eye = torch.eye(4, dtype=self.dtype, device=self.device).expand(B, 4, 4)
        mats = [frames[name].get_matrix() if name in frames else eye for name in self.hand.link_names]
        return torch.stack(mats, dim=1)

    def joint_frames(self, theta):
        """``theta (B, 21)`` → ``T_world_child (B, 21, 4, 4)``, one frame per joint (the moving links)."""
        return self.fk(theta)[:, 1:]
