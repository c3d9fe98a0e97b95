"""Sculpting by hand: the shadow of a pose an artist sets joint by joint, scored against a frame's target, and kept
as that frame's keyframe result.

The Jog tab moves the hand (or only its shadow, when no servos are connected) a joint at a time; this module is the
engine under it (DESIGN §5.7: the panel holds widgets, this decides). A pose's shadow is rendered as the audience
sees it, with the project's mount roll, at the project's frame side, and scored with the same crop-aligned losses as
an optimisation (the project's weights; no CLIP, which needs a model and a second): so a sculpted pose and an
optimised one compare on one scale. :func:`keep_pose` puts the pose into the project at a frame: the keyframe that
frame represents gets it as its result, or the frame first becomes a keyframe of its own (both edits undoable).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, replace

import numpy as np

from studio.project.status import ProjectHandle
from studio.sim.hand import Hand, load_hand


@dataclass(frozen=True)
class SculptedPose:
    """One pose as the audience would see it, and how well it imitates a frame's target (plain data)."""

    theta: np.ndarray  # (21,) rad, the hand's joint order
    shadow: np.ndarray  # (S, S) uint8 {0, 1}: its shadow on the backdrop, the project's mount roll applied
    loss: dict[str, float]  # loss components against the frame's target (studio.imitate.config.COMPONENTS)
    collision_free: bool  # the pose does not penetrate itself


class Sculptor:
    """Renders and scores poses for projects (module doc); the renderer and collision world are built once per
    frame side and roll. Thread-safe (the Jog tab's read-back thread and the kernel may both call it)."""

    def __init__(self, hand: Hand | None = None):
        self.hand = hand or load_hand()
        self._renderers: dict[tuple[int, float], object] = {}
        self._world = None
        self._lock = threading.Lock()

    def _renderer(self, side: int, roll: float):
        from studio.sim.shadow import Rig, ShadowRenderer

        key = (int(side), float(roll))
        if key not in self._renderers:
            self._renderers = {key: ShadowRenderer(self.hand, Rig(resolution=int(side), roll=float(roll)))}
        return self._renderers[key]

    def shadow(self, project: ProjectHandle, theta: np.ndarray) -> np.ndarray:
        """``(S, S)`` uint8: the shadow of ``theta (21,)`` rad (clipped to the joint limits) on the project's rig."""
        with self._lock:
            th = np.clip(np.asarray(theta, np.float64), self.hand.lower, self.hand.upper)
            return self._renderer(project.state.video.size, project.mount.roll).render_one(th)

    def score(self, project: ProjectHandle, frame: int, theta: np.ndarray) -> SculptedPose:
        """``theta (21,)`` rad as the keyframe of ``frame`` would hold it: its shadow, its losses against that frame's
        target and expressive mask, and whether it collides."""
        from studio.imitate.losses import ImageLoss
        from studio.imitate.rendered_loss import RenderedLoss
        from studio.project.jobs import project_loss
        from studio.sim.physics import CollisionWorld

        th = np.clip(np.asarray(theta, np.float64), self.hand.lower, self.hand.upper)
        shadow = self.shadow(project, th)
        target = np.array(project.state.targets[frame])  # writable copies (torch)
        expressive = np.array(project.combined_mask(frame))
        cfg = replace(project_loss(project, target.shape[-1]), use_clip=False)
        loss_fn = RenderedLoss(ImageLoss(target, cfg, expressive=expressive if expressive.any() else None))
        _, parts = loss_fn(shadow[None])
        with self._lock:
            if self._world is None:
                self._world = CollisionWorld(self.hand)
            free = not bool(self._world.in_collision(th)[0])
        return SculptedPose(th, shadow, {n: float(v[0]) for n, v in parts.items()}, free)

    def close(self) -> None:
        """Release the collision world (PyBullet)."""
        with self._lock:
            if self._world is not None:
                self._world.close()
                self._world = None


def keyframe_at(project: ProjectHandle, frame: int) -> int | None:
    """The keyframe whose representative is ``frame`` (None: the frame only plays another keyframe's pose)."""
    return next((kf.id for kf in project.keyframes if kf.representative == frame), None)


def keep_pose(project, frame: int, pose: SculptedPose) -> int:
    """Put ``pose`` into ``project`` at ``frame``: the result of the keyframe ``frame`` represents, after making the
    frame a keyframe of its own when it is not one; returns the keyframe id. Current until its inputs change."""
    if not 0 <= frame < len(project.frames):
        from studio.project.state import ProjectError

        raise ProjectError(f"no frame {frame}: the project has frames 0 to {len(project.frames) - 1}")
    k = keyframe_at(project, frame)
    if k is None:
        k = project.add_keyframe(frame)
    project.set_result(k, pose.theta, pose.loss, pose.shadow, collision_free=pose.collision_free)
    return k
