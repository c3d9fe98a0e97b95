"""What the show preview's tests share (tests/test_show_preview.py: the engine; tests/test_show_player.py: the
player and strip in Python and in the browser): the horse project posed and planned, and pixel helpers."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from studio.assets import asset

from studio.motion.plan import PlanConfig, plan_show
from studio.motion.timing import TimingConfig
from studio.project.preview import PreviewConfig, ShowPreview, preview_inputs, render_preview
from studio.project.project import Project
from studio.sim.shadow import Rig, ShadowRenderer
from studio.targets.video import VideoConfig

TILE = 160  # the preview's column side (PreviewConfig's default)
ROLL_DEG = 25.0  # the project's mount roll: the preview's shadows must be rendered with it
COLUMNS = {"source": slice(0, TILE), "target": slice(TILE + 4, 2 * TILE + 4), "shadow": slice(2 * TILE + 8, None)}


def column(rgb: np.ndarray, name: str) -> np.ndarray:
    return rgb[:, COLUMNS[name]]


def dark(rgb: np.ndarray) -> np.ndarray:
    """Shadow pixels of a decoded tile: dark (the studio shows dark shadow on a light backdrop)."""
    return rgb.astype(float).mean(axis=2) < 128


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def poses(hand, n: int) -> list[np.ndarray]:
    """n distinct poses: the wrist swinging and two fingers curling a little more each time."""
    out = []
    for i in range(n):
        q = hand.rest_pose().copy()
        q[hand.joint_names.index("wrist")] = [-0.6, 0.0, 0.6, 0.2, -0.3, 0.4][i % 6]
        for joint in ("index_mcp_flex", "middle_mcp_flex"):
            q[hand.joint_names.index(joint)] = 0.25 * (i + 1)
        out.append(q)
    return out


def horse(folder, roll: float = ROLL_DEG) -> Project:
    return Project.create(folder / "horse.shadow", sources=[asset("videos/muybridge_horse.gif")],
                          video=VideoConfig(size=64), roll=roll)  # fmt: skip


def give_results(project: Project, hand, which=None) -> None:
    rig = Rig(resolution=project.state.targets.shape[-1], roll=project.mount.roll)
    for kf, q in zip(project.keyframes, poses(hand, len(project.keyframes))):
        if which is None or kf.id in which:
            shadow = ShadowRenderer(hand, rig).render_one(q)
            project.set_result(kf.id, q, {"total": 0.1 + kf.id / 100}, shadow, inputs=project.keyframe_inputs(kf.id))


def plan(project: Project, hand) -> None:
    timing = project.show_timing()
    show = plan_show(hand, timing.keyframes, PlanConfig(timing=TimingConfig(allow_late=True))).show
    project.set_show(replace(show, roll=project.mount.roll), inputs=project.show_inputs())


def planned_horse(folder, hand) -> tuple[Project, ShowPreview]:
    """The horse (5 frames, 5 keyframes) at 64² masks in ``folder``, every keyframe posed differently, its show
    planned (faster than the servos: late transitions stretched), mounted rolled by ROLL_DEG; with its preview."""
    project = horse(folder)
    give_results(project, hand)
    plan(project, hand)
    return project, render_preview(preview_inputs(project), PreviewConfig())
