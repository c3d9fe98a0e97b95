"""One engine, three faces: the same source through ``imitate-video``, ``project new`` + ``project run`` and the
notebook's Optimise tab gives the same keyframes, poses and show (studio.project.pipeline, Project.run)."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from studio.imitate.config import CPU_SEQUENCE, RefineConfig, SearchConfig, SweepConfig
from studio.motion.show import load_show
from studio.project.project import Project
from studio.project.run import RunConfig

pytestmark = pytest.mark.slow

TINY = ["--search-batch", "8", "--search-iterations", "15", "--next-batch", "4", "--next-iterations", "8",
        "--refine-steps", "15", "--refine-restarts", "2", "--candidates", "1", "--sweep-draws", "64",
        "--sweep-passes", "1", "--joint-generations", "10"]  # fmt: skip
SOURCE = ["--fps", "8", "--hz", "4"]
SERVOS = ["--allow-late"]
SEQUENCE = CPU_SEQUENCE.__class__(
    first=SearchConfig(batch=8, iterations=15, lr=CPU_SEQUENCE.first.lr),
    next=SearchConfig(batch=4, iterations=8, lr=CPU_SEQUENCE.next.lr),
    refine=RefineConfig(**{**CPU_SEQUENCE.refine.__dict__, "steps": 15, "restarts": 2}),
    candidates=1, retrieve=CPU_SEQUENCE.retrieve,
    sweep=SweepConfig(**{**CPU_SEQUENCE.sweep.__dict__, "draws": 64, "passes": 1}),
    joint=replace(CPU_SEQUENCE.joint, generations=10),
)  # the notebook's settings, the same budget as TINY  # fmt: skip


def _outcome(project: Project) -> tuple[list, np.ndarray, np.ndarray]:
    """(keyframes as (representative, members), poses (K, 21) in first-appearance order, the show's positions)."""
    from studio.sim.hand import load_hand

    names = load_hand().joint_names
    keyframes = [(kf.representative, tuple(kf.members)) for kf in project.keyframes]
    poses = np.stack([project.results[kf.id].theta(names) for kf in project.keyframes])
    return keyframes, poses, np.asarray(project.show.positions)


@pytest.mark.slow
def test_three_faces_give_the_same_keyframes_poses_and_show(tmp_path, sources, in_process):
    clip, _ = sources
    # 1. the command line's one-source verb
    cli = in_process("imitate-video", clip, "--out", tmp_path / "cli", "--no-clip", "--quiet", *SOURCE, *TINY, *SERVOS)
    assert cli.returncode == 0, cli.stderr[-2000:]
    verb = Project.open(tmp_path / "cli" / "clip.shadow")
    # 2. a project made and run from the command line
    made = in_process("project", "new", tmp_path / "p.shadow", "--source", clip, *SOURCE)
    assert made.returncode == 0, made.stderr[-2000:]
    ran = in_process("project", "run", tmp_path / "p.shadow", "--no-clip", "--quiet", *TINY, *SERVOS)
    assert ran.returncode == 0, ran.stderr[-2000:]
    project_cli = Project.open(tmp_path / "p.shadow")
    # 3. the notebook: the Optimise tab's "All stale" on a project made in Python
    from studio.project.jobs import queue_for
    from studio.targets.video import VideoConfig
    from widgets.optimise import OptimiseConfig, optimise_panel
    from widgets.state import StudioState

    notebook = Project.create(tmp_path / "nb.shadow", sources=[clip], video=VideoConfig(fps=8, hz=4))
    state = StudioState(notebook, queue_for(notebook))
    panel = optimise_panel(state, OptimiseConfig(sequence=SEQUENCE, allow_late=True))
    try:
        panel.start("stale")
        deadline = time.monotonic() + 300
        while panel.report is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert panel.report is not None and panel.report.ok, panel.report and panel.report.message
    finally:
        panel.close()
        state.close()
    a, b, c = _outcome(verb), _outcome(project_cli), _outcome(notebook)
    assert a[0] == b[0] == c[0] and len(a[0]) >= 2  # the same keyframes …
    np.testing.assert_array_equal(a[1], b[1])  # … the same poses, to the bit (same seeds, same engine calls) …
    np.testing.assert_array_equal(a[1], c[1])
    np.testing.assert_array_equal(a[2], b[2])  # … and the same show
    np.testing.assert_array_equal(a[2], c[2])
    # and the verb's files are the project's: its show file, its keyframes file
    shown = load_show(tmp_path / "cli" / "show.json")
    np.testing.assert_array_equal(shown.positions, a[2])
    doc = json.loads((tmp_path / "cli" / "keyframes.json").read_text())
    assert [p["id"] for p in doc["poses"]] == [kf.id for kf in verb.keyframes]


@pytest.mark.slow
def test_the_public_api_runs_a_video_to_a_show(tmp_path, sources):
    import studio

    clip, _ = sources
    settings = studio.SourceSettings(video=studio.VideoConfig(fps=8, hz=4))
    result = studio.imitate_video(clip, tmp_path / "api", settings, RunConfig(sequence=SEQUENCE, allow_late=True))
    assert result.show is not None and result.report.ok and result.fresh
    assert result.thetas.shape == (len(result.project.keyframes), 21)
    assert set(result.files) == {"keyframes.json", "show.json", "contact.png", "side_by_side.mp4", "review.rrd"}
    again = studio.imitate_video(clip, tmp_path / "api", settings, RunConfig(sequence=SEQUENCE, allow_late=True))
    assert not again.fresh and again.report.optimised == [] and again.report.show == "current"
    assert Path(again.files["show.json"]).is_file()
