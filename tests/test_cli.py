"""The console script as a user runs it: a real subprocess, one-line errors, no tracebacks."""

from __future__ import annotations

import json
import subprocess
import sys

import cv2
import numpy as np


def run(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "studio.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=300
    )


def test_help_lists_verbs():
    out = run("--help")
    assert out.returncode == 0
    for verb in ("render", "collect", "gen-urdf"):
        assert verb in out.stdout


def test_render_rest_and_json_pose(tmp_path, hand):
    out = run("render", "rest", "--out", str(tmp_path / "rest.png"), "--resolution", "128")
    assert out.returncode == 0, out.stderr
    img = cv2.imread(str(tmp_path / "rest.png"), cv2.IMREAD_GRAYSCALE)
    assert img.shape == (128, 128) and img.min() == 0 and img.max() == 255
    pose = hand.pose_to_dict(hand.rest_pose())
    pose["index_mcp_flex"] = 1.2
    (tmp_path / "pose.json").write_text(json.dumps(pose))
    out = run("render", str(tmp_path / "pose.json"), "--out", str(tmp_path / "p.png"), "--mask")
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert summary["pose"]["index_mcp_flex"] == 1.2
    mask = cv2.imread(str(tmp_path / "p.png"), cv2.IMREAD_GRAYSCALE) > 127
    assert mask.sum() == summary["shadow_pixels"]


def test_render_errors_are_one_line(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"wrist": 5.0}))
    for args, message in (
        (("render", str(tmp_path / "absent.json")), "pose file not found"),
        (("render", str(bad)), "missing"),
        (("render", "[broken"), "pose file not found"),
    ):
        out = run(*args, "--out", str(tmp_path / "x.png"))
        assert out.returncode == 2
        assert message in out.stderr and "Traceback" not in out.stderr


def test_out_of_limit_pose_is_refused(tmp_path, hand):
    pose = hand.pose_to_dict(hand.rest_pose())
    pose["wrist"] = 2.5
    (tmp_path / "pose.json").write_text(json.dumps(pose))
    out = run("render", str(tmp_path / "pose.json"), "--out", str(tmp_path / "x.png"))
    assert out.returncode == 2 and "wrist = 2.5000 rad is outside its limits" in out.stderr


def test_collect_and_resume(tmp_path):
    args = ("collect", "--n", "120", "--shard-size", "50", "--resolution", "32", "--out", str(tmp_path), "--quiet")
    first = run(*args)
    assert first.returncode == 0, first.stderr
    s1 = json.loads(first.stdout.strip().splitlines()[-1])
    assert s1["written"] == 3 and s1["samples"] == 120
    second = json.loads(run(*args).stdout.strip().splitlines()[-1])
    assert second["written"] == 0 and second["skipped"] == 3
    clash = run("collect", "--n", "120", "--resolution", "64", "--out", str(tmp_path), "--quiet")
    assert clash.returncode == 2 and "different dataset" in clash.stderr


def test_gen_urdf_check():
    out = run("gen-urdf", "--check")
    assert out.returncode == 0 and "up to date" in out.stdout


def test_shipped_pose_renders_like_library(tmp_path, hand):
    from studio.sim.shadow import Rig, ShadowRenderer

    run("render", "random", "--seed", "4", "--out", str(tmp_path / "r.png"), "--mask", "--resolution", "64")
    mask = (cv2.imread(str(tmp_path / "r.png"), cv2.IMREAD_GRAYSCALE) > 127).astype(np.uint8)
    from studio.sim.sampling import sample_poses

    theta = sample_poses(hand, 1, np.random.default_rng(4))[0][0]
    assert np.array_equal(mask, ShadowRenderer(hand, Rig(resolution=64)).render_one(theta))
