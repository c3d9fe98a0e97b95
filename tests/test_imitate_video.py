"""``shadow-studio imitate-video`` end to end in subprocesses, on the bundled horse with a small budget: a one-source
project, its files, the show at the video's clock, cancel and resume."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from studio.review.blueprint import FRAME, POSE, SHOW_TIME, SOURCE, TARGET
from studio.review.readback import read_recording
from studio.targets.video import DEFAULT_VIDEO

SMALL = ["--no-clip", "--quiet", "--hz", "4", "--search-batch", "8", "--search-iterations", "20", "--next-batch",
         "4", "--next-iterations", "10", "--refine-steps", "20", "--refine-restarts", "2", "--candidates", "1",
         "--sweep-draws", "96", "--sweep-passes", "1", "--joint-generations", "10"]  # fmt: skip
FAST_SERVOS = ["--acceleration", "200", "--jerk", "5000"]  # servos fast enough for a 1.1 s gallop at 4 Hz
SLOW_SERVOS = ["--velocity-scale", "0.05", "--no-keep-clock"]  # far too slow for it (poses chosen without the clock)
UNSEEDED = ["--no-retrieve"]  # tests about timing and footage: no seeding sweep (the first fixture run seeds)
FILES = ("keyframes.json", "show.json", "contact.png", "side_by_side.mp4", "review.rrd")


def cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "studio.cli", *map(str, args)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


def summary(proc: subprocess.CompletedProcess) -> dict:
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def horse(tmp_path_factory) -> tuple[Path, dict]:
    out = tmp_path_factory.mktemp("horse")
    proc = cli("imitate-video", DEFAULT_VIDEO, "--out", out, *SMALL, *FAST_SERVOS)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return out, summary(proc)


@pytest.mark.slow
def test_writes_a_project_every_file_and_a_summary(horse):
    out, s = horse
    for name in FILES:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    project = out / "muybridge_horse.shadow"
    assert s["project"] == str(project) and (project / "project.json").is_file()
    assert s["frames"] == 5 and 1 <= s["keyframes"] <= 5 and s["fresh_project"]
    assert s["keyframes_optimised"] and not s["keyframes_skipped"]
    assert s["transitions"] == s["keyframes"] - 1 and 0 <= s["transition_success"] <= 1
    assert s["show"] == str(out / "show.json") and s["late_transitions"] == [] and s["collision_free"]


@pytest.mark.slow
def test_validate_accepts_the_show_and_it_lasts_as_long_as_the_video(horse):
    out, s = horse
    proc = cli("validate", out / "show.json")
    assert proc.returncode == 0 and "valid show" in proc.stdout, proc.stderr
    show = json.loads((out / "show.json").read_text())
    duration = show["samples"][-1][0]
    assert duration == pytest.approx(1.1, abs=0.25)  # the GIF's 1.1 s, ±1 sample frame at 4 Hz
    assert duration == pytest.approx(s["video_seconds"], abs=1e-9)  # on the video's own clock, to the sample
    assert show["media"] == {"path": str(Path(DEFAULT_VIDEO).resolve()), "kind": "video", "offset_s": 0.0}


@pytest.mark.slow
def test_keyframes_json_follows_the_video_and_plans(horse, tmp_path):
    out, s = horse
    doc = json.loads((out / "keyframes.json").read_text())
    times = [f["t"] for f in doc["frames"]]
    assert doc["complete"] and len(doc["assignment"]) == len(times) == 5 and len(doc["poses"]) == s["keyframes"]
    kf = doc["keyframes"]
    assert kf[0]["t"] == 0.0 and kf[-1]["t"] == pytest.approx(s["video_seconds"])
    for k in kf[:-1]:  # every planner keyframe sits at a sampled frame's source time and plays its keyframe's pose
        assert k["t"] == pytest.approx(times[k["frame"]])
        pose = next(p for p in doc["poses"] if p["id"] == k["keyframe"])
        assert doc["assignment"][k["frame"]] == pose["keyframe"] and k["pose"] == pytest.approx(pose["pose"])
        assert k["source_frame"] == doc["frames"][k["frame"]]["source_frame"]
        assert k["loss"] == pytest.approx(pose["loss"]["total"])
    assert doc["provenance"]["no_clip"] and doc["provenance"]["sequence"]["first"]["batch"] == 8
    proc = cli("plan", out / "keyframes.json", "--out", tmp_path / "replanned.json", *FAST_SERVOS)
    assert proc.returncode == 0, proc.stderr
    replanned = json.loads((tmp_path / "replanned.json").read_text())
    assert replanned["samples"][-1][0] == pytest.approx(s["video_seconds"])


@pytest.mark.slow
def test_side_by_side_reads_back_at_the_source_rate(horse):
    out, s = horse
    cap = cv2.VideoCapture(str(out / "side_by_side.mp4"))
    frames = []
    while True:
        ok, frame = cap.read()
        if not ok:
            break
        frames.append(frame)
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(10.0)  # the GIF's 10 frames per second
    cap.release()
    assert len(frames) == round(s["video_seconds"] * 10)
    assert frames[0].shape[1] > 2.5 * frames[0].shape[0]  # three panels side by side
    h = frames[0].shape[0]
    left, right = frames[0][:, :h].astype(int), frames[0][:, -h:].astype(int)
    assert left.std() > 5 and right.std() > 5  # the source frame and the show's shadow are drawn, not blank


@pytest.mark.slow
def test_review_is_the_one_project_format_with_the_source_and_the_show(horse):
    out, s = horse
    rec = {e.lstrip("/"): v for e, v in read_recording(out / "review.rrd").items()}
    for entity in (TARGET, SOURCE):  # on frame, and on show_time where the show plays each frame
        assert rec[entity]["timelines"] - {"log_time"} == {FRAME, "show_time"}, entity
        assert rec[entity]["rows"] == 2 * s["frames"], entity
    show = json.loads((out / "show.json").read_text())
    poses = [e for e, v in rec.items() if e.startswith(POSE + "/") and not v["static"]]
    assert len(poses) == 21  # one transform per joint (and the root link's, static, at the world origin)
    assert [e for e, v in rec.items() if e.startswith(POSE + "/") and v["static"]] == [f"{POSE}/forearm"]
    assert all(SHOW_TIME in rec[e]["timelines"] for e in poses)
    assert any(e.startswith("world/hand") and v["static"] for e, v in rec.items())  # the hand from the URDF, once
    assert len(show["keyframes"]) >= 2


@pytest.mark.slow
def test_too_fast_for_the_servos_reports_and_allow_late_stretches(tmp_path):
    strict = cli("imitate-video", DEFAULT_VIDEO, "--out", tmp_path / "strict", *SMALL, *UNSEEDED, *SLOW_SERVOS)
    assert strict.returncode == 1, strict.stderr[-2000:]
    s = summary(strict)
    assert s["show"] is None and s["late_transitions"] and not (tmp_path / "strict" / "show.json").exists()
    late = s["late_transitions"][0]
    assert late["needed_s"] > late["given_s"] and late["to_frame"] >= 1
    assert f"frame {late['to_frame']}" in strict.stdout and "--allow-late" in strict.stderr.splitlines()[-1]
    for name in set(FILES) - {"show.json", "side_by_side.mp4"}:
        assert (tmp_path / "strict" / name).is_file(), name
    # the same folder again, now stretching: the project is reopened, no keyframe is recomputed
    stretched = cli("imitate-video", DEFAULT_VIDEO, "--out", tmp_path / "strict", *SMALL, *UNSEEDED, *SLOW_SERVOS,
                    "--allow-late")  # fmt: skip
    assert stretched.returncode == 0, stretched.stderr[-2000:]
    s2 = summary(stretched)
    assert not s2["fresh_project"] and s2["keyframes_optimised"] == [] and s2["keyframes_skipped"]
    assert s2["late_transitions"] == s["late_transitions"] and s2["show_seconds"] > s2["video_seconds"]
    assert cli("validate", tmp_path / "strict" / "show.json").returncode == 0


@pytest.mark.slow
def test_ctrl_c_keeps_the_finished_keyframes_and_the_same_command_resumes(tmp_path):
    out = tmp_path / "cancel"
    budget = [a if a != "10" else "100000" for a in SMALL]  # later keyframes: a search far too long to finish
    cmd = [sys.executable, "-m", "studio.cli", "imitate-video", str(DEFAULT_VIDEO), "--out", str(out), *budget]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        for line in proc.stderr:
            if "keyframe 1/1: total" in line:  # logged when the first keyframe is finished
                os.kill(proc.pid, signal.SIGINT)
                break
        stdout, stderr = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr[-2000:]
    doc = json.loads((out / "keyframes.json").read_text())
    assert not doc["complete"] and doc["keyframes"] == [] and len(doc["poses"]) >= 1 and (out / "contact.png").is_file()
    assert not (out / "show.json").exists() and json.loads(stdout.strip().splitlines()[-1])["cancelled"]
    done = [p["id"] for p in doc["poses"]]
    again = cli("imitate-video", DEFAULT_VIDEO, "--out", out, *SMALL, "--allow-late")
    assert again.returncode == 0, again.stderr[-2000:]
    s = summary(again)
    assert set(done) <= set(s["keyframes_skipped"]) and not set(done) & set(s["keyframes_optimised"])
    other = cli("imitate-video", DEFAULT_VIDEO, "--out", out, *SMALL, "--hz", "8")
    _one_line_error(other, "made otherwise", "--fresh")


@pytest.mark.slow
def test_raw_footage_is_segmented_from_a_first_mask(shared_targets, tmp_path):
    """DAVIS blackswan colour frames (its first second) with the ground truth's first mask, then its box."""
    rgb, truth = tmp_path / "blackswan", shared_targets / "davis" / "blackswan"
    rgb.mkdir()
    for f in sorted((shared_targets / "davis-rgb" / "blackswan").glob("*.jpg"))[:24]:
        (rgb / f.name).write_bytes(f.read_bytes())
    out = tmp_path / "swan"
    proc = cli("imitate-video", rgb, "--out", out, "--first-mask", truth / "00000.png", *SMALL, *UNSEEDED,
               "--allow-late")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    s = summary(proc)
    assert s["frames"] == 4 and s["video_seconds"] == pytest.approx(1.0)  # 24 frames at 24 fps, sampled at 4 Hz
    doc = json.loads((out / "keyframes.json").read_text())
    assert doc["sources"][0]["footage"] == "segmented" and [f["source_frame"] for f in doc["frames"]] == [0, 6, 12, 18]
    rec = {e.lstrip("/"): v for e, v in read_recording(out / "review.rrd").items()}
    assert rec[TARGET]["rows"] == 2 * 4  # on frame and on show_time
    box = cli("imitate-video", rgb, "--out", tmp_path / "o", "--box", "1,2,3", "--quiet")
    _one_line_error(box, "--box", "x,y,w,h")


def _one_line_error(proc: subprocess.CompletedProcess, *words: str) -> None:
    assert proc.returncode == 2, (proc.stdout, proc.stderr)
    lines = [x for x in proc.stderr.splitlines() if x.strip() and not x.startswith(("INFO", "WARNING"))]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for w in words:
        assert w in lines[0], lines[0]


@pytest.mark.slow
def test_bad_input_is_one_line_and_exit_2(tmp_path, in_process):
    _one_line_error(
        cli("imitate-video", tmp_path / "missing.gif", "--out", tmp_path / "o", "--no-clip", "--quiet"), "not found"
    )
    run = in_process  # the rest in this process (the one start above proves the console script)
    junk = tmp_path / "junk.gif"
    junk.write_bytes(b"not a gif at all")
    _one_line_error(run("imitate-video", junk, "--out", tmp_path / "o", "--no-clip", "--quiet"), "junk.gif")
    colour = tmp_path / "colour.avi"
    writer = cv2.VideoWriter(str(colour), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (64, 48))
    rng = np.random.default_rng(0)
    for _ in range(10):
        writer.write(rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    writer.release()
    _one_line_error(
        run("imitate-video", colour, "--out", tmp_path / "o", "--no-clip", "--quiet"), "colour footage", "--box"
    )
    _one_line_error(run("imitate-video", DEFAULT_VIDEO, "--out", tmp_path / "o", "--hz", "0"), "hz")
    _one_line_error(run("imitate", DEFAULT_VIDEO, "--out", tmp_path / "o"), "imitate-video")
    assert not (tmp_path / "o").exists()
