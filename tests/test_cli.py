"""The console script as a user runs it: a real subprocess, one-line errors, no tracebacks."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest


def run(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "studio.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=300
    )


@pytest.mark.slow
def test_help_lists_verbs():
    out = run("--help")
    assert out.returncode == 0
    for verb in ("render", "collect", "gen-urdf"):
        assert verb in out.stdout


def test_each_verb_is_registered_by_the_module_the_dispatch_names():
    """main() builds only the module of the verb on the command line: VERBS must name every verb's module."""
    import importlib

    from studio.cli.flags import CliParser
    from studio.cli.main import VERB_MODULES, VERBS, verb_modules_for

    registered = {}
    for name in VERB_MODULES:
        sub = CliParser(prog="t").add_subparsers(dest="verb")
        importlib.import_module(name).register(sub)
        registered |= dict.fromkeys(sub.choices, name)
    assert registered == VERBS
    assert verb_modules_for(["-v", "play", "show.json"]) == ("studio.cli.servos",)
    assert verb_modules_for(["--help"]) == verb_modules_for(["no-such-verb"]) == VERB_MODULES


@pytest.mark.slow
def test_every_verb_starts_without_torch():
    """Every verb's parser is built from torch-free configs, so `--help`, a bad flag or a missing file answer at
    once (and `play`, `scan`, `render` never need torch on a Raspberry Pi beside the hand)."""
    code = ("import atexit, sys; atexit.register(lambda: print('torch loaded:', 'torch' in sys.modules)); "
            "from studio.cli.main import main; sys.exit(main(sys.argv[1:]))")  # fmt: skip

    def start(*argv: str, rc: int = 0) -> str:
        out = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120)
        assert out.returncode == rc and "Traceback" not in out.stderr, (argv, out.stderr)
        return out.stdout + out.stderr

    from studio.cli.main import VERBS

    build = "; ".join(f"build_parser(({m!r},))" for m in sorted(set(VERBS.values())))
    probe = "import sys; from studio.cli.main import build_parser; " + build + "; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "False", out.stderr  # all verbs' parsers, no torch
    for verb in ("scan", "imitate", "evaluate", "project"):
        assert "torch loaded: False" in start(verb, "--help"), verb
    assert "torch loaded: False" in start("imitate", "--search-batch", "0", rc=2)
    missing = start("evaluate", "/no/such/folder", "--out", "x", rc=2)
    assert "torch loaded: False" in missing and "not found: /no/such/folder" in missing
    assert "imitate-video" in start("--help")  # --help still lists every verb


@pytest.mark.slow
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


@pytest.mark.slow
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


@pytest.mark.slow
def test_shipped_pose_renders_like_library(tmp_path, hand):
    from studio.sim.shadow import Rig, ShadowRenderer

    run("render", "random", "--seed", "4", "--out", str(tmp_path / "r.png"), "--mask", "--resolution", "64")
    mask = (cv2.imread(str(tmp_path / "r.png"), cv2.IMREAD_GRAYSCALE) > 127).astype(np.uint8)
    from studio.sim.sampling import sample_poses

    theta = sample_poses(hand, 1, np.random.default_rng(4))[0][0]
    assert np.array_equal(mask, ShadowRenderer(hand, Rig(resolution=64)).render_one(theta))


def _one_line_error(out: subprocess.CompletedProcess, words: str) -> None:
    assert out.returncode == 2, (out.returncode, out.stderr)
    assert out.stderr.count("\n") == 1 and "Traceback" not in out.stderr, out.stderr
    assert words in out.stderr, out.stderr


@pytest.mark.slow
def test_crashing_values_are_one_line_errors(tmp_path):
    """Values that used to crash (--candidates 0 refined the whole batch, --threads 0) or were silently replaced
    (--search-batch 0 became the preset's 32) are refused before any work starts."""
    target, out = "assets/targets/asl_o.jpeg", str(tmp_path / "o")
    for flag, top in (("--candidates", 64), ("--threads", 256), ("--search-batch", 2048)):
        proc = run("imitate", target, "--out", out, flag, "0", cwd=Path(__file__).resolve().parents[1])
        _one_line_error(proc, f"shadow-studio imitate: error: argument {flag}: must be in [1, {top}], got 0")
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (("imitate", "t.png", "--out", "o", "--search-iterations", "0"), "--search-iterations: must be in [1, 100000]"),
        (("imitate", "t.png", "--out", "o", "--refine-steps", "-1"), "--refine-steps: must be in [0, 100000], got -1"),
        (("imitate", "t.png", "--out", "o", "--gap-s", "-1"), "argument --gap-s: must be in [0, 3600], got -1"),
        (("imitate", "t.png", "--out", "o", "--still-hold-s", "inf"), "expected a finite number, got 'inf'"),
        (("imitate", "t.png", "--out", "o", "--still-threshold", "255"), "--still-threshold: must be in [0, 255)"),
        (("imitate", "t.png", "--out", "o", "--preset", "cpu"), "invalid choice: 'cpu'"),
        (("evaluate", "t.png", "--out", "o", "--search-batch", "0"), "--search-batch: must be in [1, 2048], got 0"),
        (("evaluate", "t.png", "--out", "o", "--refine-restarts", "0"), "--refine-restarts: must be in [1, 64]"),
        (("evaluate", "t.png", "--out", "o", "--threads", "-1"), "argument --threads: must be in [0, 256], got -1"),
        (("collect", "--n", "0"), "argument --n: must be in [1, 10000000], got 0"),
        (("render", "rest", "--resolution", "4"), "argument --resolution: must be in [8, 8192], got 4"),
        (("plan", "poses.json", "--out", "o", "--jerk", "0"), "argument --jerk: must be in [0.01, 1000000], got 0"),
        (("plan", "poses.json", "--out", "o", "--velocity-scale", "1.5"), "must be in [0.01, 1], got 1.5"),
        (("nonsense",), "invalid choice: 'nonsense'"),
    ],
)
def test_out_of_range_flags_are_one_line_argparse_errors(capsys, argv, words):
    from studio.cli.main import main

    with pytest.raises(SystemExit) as e:
        main(list(argv))
    err = capsys.readouterr().err
    assert e.value.code == 2 and err.count("\n") == 1 and words in err, err


BOOM_VERB = """
def register(sub):
    p = sub.add_parser("boom", help="raise an unexpected exception (a stand-in for a bug)")
    p.set_defaults(func=lambda args: {}["missing key"])
"""


def _run_boom(tmp_path, *args: str) -> subprocess.CompletedProcess:
    (tmp_path / "boom_verb.py").write_text(BOOM_VERB)
    code = "import sys; from studio.cli.main import main; sys.exit(main(sys.argv[1:], verb_modules=['boom_verb']))"
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, env=env, timeout=120)


def test_a_bug_is_one_line_and_verbose_shows_the_traceback(tmp_path):
    quiet = _run_boom(tmp_path, "boom")
    assert quiet.returncode == 1 and "Traceback" not in quiet.stderr
    assert quiet.stderr.strip().splitlines() == [
        "shadow-studio boom: internal error: KeyError: 'missing key' (run with -v for the traceback)"
    ]
    loud = _run_boom(tmp_path, "-v", "boom")
    assert loud.returncode == 1
    assert "Traceback (most recent call last)" in loud.stderr and "KeyError: 'missing key'" in loud.stderr
    assert "boom_verb.py" in loud.stderr  # the frame of the bug is shown


def test_user_errors_stay_one_line_but_verbose_adds_the_traceback(tmp_path):
    quiet = run("render", str(tmp_path / "absent.json"), "--out", str(tmp_path / "x.png"))
    _one_line_error(quiet, "pose file not found")
    loud = run("-v", "render", str(tmp_path / "absent.json"), "--out", str(tmp_path / "x.png"))
    assert loud.returncode == 2 and "Traceback" in loud.stderr
    assert loud.stderr.strip().splitlines()[-1] == quiet.stderr.strip()


@pytest.mark.slow
def test_plan_one_keyframe_at_zero_holds_that_pose(tmp_path, hand):
    """The single keyframe at t = 0 (what `imitate --at 0` writes) plans to a one-sample show holding the pose."""
    from studio.motion.show import load_show

    pose = hand.pose_to_dict(hand.rest_pose())
    pose["index_mcp_flex"] = 0.8
    (tmp_path / "pose.json").write_text(json.dumps({"keyframes": [{"t": 0.0, "pose": pose, "hold": True}]}))
    out = run("plan", str(tmp_path / "pose.json"), "--out", str(tmp_path / "show.json"))
    assert out.returncode == 0, out.stderr
    assert "holds that pose" in out.stdout
    show = load_show(tmp_path / "show.json")
    assert show.times.tolist() == [0.0] and show.duration == 0.0
    assert np.array_equal(show.positions[0], [pose[n] for n in show.joint_names])
    assert [k.t for k in show.keyframes] == [0.0]
