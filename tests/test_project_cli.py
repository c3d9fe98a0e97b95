"""The ``project new/info/export`` verbs as a user runs them: a real console script end to end, bad input as one
line with exit code 2, the still-target flags reaching the project's configs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from studio.assets import asset

from studio.motion.show import Show, load_show
from studio.project.project import Project
from studio.targets.images import TargetConfig
from studio.targets.video import VideoConfig

VIDEO = VideoConfig(size=32, fps=8.0, hz=8.0)
CLI = [sys.executable, "-m", "studio.cli.main"]


def cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=300, cwd=cwd)


@pytest.mark.slow
def test_project_verbs_end_to_end(tmp_path, shared_targets, hand):
    davis = shared_targets / "davis" / "blackswan"
    if not davis.is_dir():
        pytest.skip(f"DAVIS masks not found at {davis}")
    still = asset("targets/asl_o.jpeg")
    r = cli("project", "new", "swan.shadow", "--source", str(davis), str(still), "--hz", "2", "--size", "48",
            "--tau", "0.39", cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    new = json.loads(r.stdout.strip().splitlines()[-1])
    assert new["size"] == 48 and new["hz"] == 2.0 and [s["kind"] for s in new["sources"]] == ["folder", "still"]
    assert new["frames"] == sum(s["frames"] for s in new["sources"]) and new["sources"][1]["frames"] == 1
    assert new["results"] == {"current": 0, "stale": 0, "missing": len(new["keyframes"])}
    assert "keyframe 0: frame" in r.stdout and new["show"] is None

    r = cli("project", "info", "swan.shadow", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    info = json.loads(r.stdout.strip().splitlines()[-1])
    assert info["keyframes"] == new["keyframes"] and "show: none planned yet" in r.stdout

    r = cli("project", "export", "swan.shadow", "--out", "show.json", cwd=tmp_path)
    assert r.returncode == 2 and "no planned show" in r.stderr and len(r.stderr.strip().splitlines()) == 1

    p = Project.open(tmp_path / "swan.shadow")
    for kf in p.keyframes:
        p.set_result(kf.id, hand.rest_pose(), {"total": 0.2}, p.keyframe_masks(kf.id)[0])
    rest = np.stack([hand.rest_pose(), hand.rest_pose()])
    p.set_show(Show.from_samples(hand, np.array([0.0, 3.0]), rest, title="test"))
    r = cli("project", "export", "swan.shadow", "--out", "show.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.strip().splitlines()[-1])["duration_s"] == 3.0
    assert load_show(tmp_path / "show.json").equals(p.show)
    r = cli("project", "info", "swan.shadow", cwd=tmp_path)
    info = json.loads(r.stdout.strip().splitlines()[-1])
    assert info["results"]["current"] == len(info["keyframes"]) and info["show"]["stale"] is False


@pytest.mark.slow
def test_project_verbs_report_bad_input_in_one_line(tmp_path, sources, in_process, monkeypatch):
    r = cli("project", "new", "x.shadow", "--source", str(tmp_path / "nothing.png"), cwd=tmp_path)
    assert r.returncode == 2 and "source not found" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    monkeypatch.chdir(tmp_path)  # the rest in this process (the start above proves the console script)
    r = in_process("project", "info", "nope.shadow")
    assert r.returncode == 2 and "project not found: nope.shadow" in r.stderr, r.stderr
    assert "(shadow-studio project new makes one)" in r.stderr
    r = in_process("project", "info", ".")  # a folder, but no project's
    assert r.returncode == 2 and "not a project (no project.json)" in r.stderr, r.stderr
    still = sources[1].relative_to(tmp_path)  # the image itself, given for its project: how to make one from it
    r = in_process("project", "run", str(still))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"{still} is a file" in r.stderr and f"project new {still.stem}.shadow --source {still}" in r.stderr
    p = Project.create(tmp_path / "p.shadow", sources=[str(s) for s in sources], video=VIDEO)
    for verb in ("play", "show-info"):  # the project given where its show file goes: how to write that file
        r = in_process(verb, "p.shadow", *(["--dry-run"] if verb == "play" else []))
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert "p.shadow: a folder, not a show file" in r.stderr and "project export p.shadow --out" in r.stderr
    doc = json.loads((p.path / "project.json").read_text())
    (p.path / "project.json").write_text(json.dumps(doc | {"version": 2}))
    r = in_process("project", "info", str(p.path))
    assert r.returncode == 2 and "version 2" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = in_process("project", "new", "t.shadow", "--source", str(sources[1]), "--still-threshold", "300")
    assert r.returncode == 2 and "still-threshold" in r.stderr


@pytest.mark.slow
def test_still_threshold_and_otsu_flags_reach_the_configs(tmp_path, sources):
    r = cli("project", "new", "t.shadow", "--source", str(sources[1]), "--still-threshold", "60", "--otsu",
            "--size", "32", cwd=tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    p = Project.open(tmp_path / "t.shadow")
    assert p.state.still == TargetConfig(threshold=60.0, auto_otsu=False)  # a level asked for is always used
    assert p.state.video.threshold is None and p.state.video.size == 32
    assert os.path.isabs(p.sources[0].absolute)


def test_a_repeated_source_flag_adds_sources(tmp_path, in_process, monkeypatch):
    """``--source a --source b`` is two sources, as ``--source a b`` is (the second flag once replaced the first)."""
    monkeypatch.chdir(tmp_path)
    stills = [asset("targets/asl_o.jpeg"), asset("targets/asl_v.jpeg")]
    r = in_process("project", "new", "two.shadow", "--source", stills[0], "--source", stills[1])
    assert r.returncode == 0, r.stderr
    assert [Path(s.path).name for s in Project.open(tmp_path / "two.shadow").sources] == ["asl_o.jpeg", "asl_v.jpeg"]
