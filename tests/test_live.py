"""Live (studio.project.live): the whole loop on the servo emulator (real pyserial over a pty) with a file camera,
the real self-model's renderer, a small real retrieval index, Ruckig online and the 40 Hz player."""

from __future__ import annotations

import json
import math
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from hardware.calibration import default_calibration, load_calibration, save_calibration
from hardware.camera import Camera
from hardware.playback_log import StopReason
from hardware.session import ServoSession
from studio.imitate.config import LivePoseConfig, LossConfig
from studio.imitate.live_pose import LivePoser
from studio.imitate.losses import ImageLoss
from studio.imitate.retrieval import RetrievalConfig, RetrievalIndex
from studio.imitate.still import Imitator
from studio.motion.plan import load_keyframes
from studio.project.live import run_live
from studio.project.live_config import LiveConfig
from studio.review.live_record import LiveRecorder
from studio.review.readback import read_recording

SMALL_INDEX = RetrievalConfig(size=3000, chunk=1500, shortlist=48, seed=7)


def silhouette(k: int, size: tuple[int, int] = (240, 320)) -> np.ndarray:
    """A BGR photograph of a dark hand-like silhouette (palm and three fingers, the fingers turning with ``k``) on an
    unevenly lit wall."""
    h, w = size
    ramp = np.linspace(200, 240, w, dtype=np.float32)[None, :].repeat(h, 0)
    img = np.dstack([ramp] * 3).astype(np.uint8)
    cx, cy = w // 2, h // 2 + 30
    cv2.ellipse(img, (cx, cy), (40, 55), 0, 0, 360, (30, 30, 30), -1)
    for f, base in enumerate((-30, 0, 30)):
        angle = np.radians(base + 10 * np.sin(k / 3 + f))
        tip = (int(cx + 110 * np.sin(angle)), int(cy - 50 - 110 * np.cos(angle)))
        cv2.line(img, (cx + base // 2, cy - 40), tip, (30, 30, 30), 14)
    return img


@pytest.fixture(scope="module")
def imitator():
    im = Imitator()
    im._index = RetrievalIndex.build(im.renderer, SMALL_INDEX)
    yield im
    im.close()


@pytest.fixture(scope="module")
def frames(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("live_frames")
    for k in range(12):
        cv2.imwrite(str(folder / f"{k:03d}.png"), silhouette(k))
    return folder


@pytest.fixture
def cal(hand):
    return load_calibration(None, hand)


def test_a_live_pose_on_a_rolled_mount_is_scored_as_the_audience_sees_it(imitator):
    """On a mount rolled by 67° the backdrop shows the held pose's rolled shadow: the live pose keeps that pose and
    scores it 0 (rendered as the rolled mount casts it, compared with the target as it is); turning the target
    into the hand's frame instead would cost the resampling of a turned 128² image."""
    roll = np.radians(67.0)
    theta = imitator.retrieval_index().theta[5].astype(np.float64)
    target = imitator.refiner.with_roll(roll).renderer.render_one(theta)
    poser = LivePoser(imitator.retrieval_index(), imitator.refiner, LivePoseConfig(budget_s=0.2), roll=roll)
    poser.previous = theta.copy()
    got = poser.pose(target)
    assert got.path_free and got.loss < 1e-6 and np.allclose(got.theta, theta), (got.loss, got.theta - theta)
    assert np.array_equal(poser.refiner.renderer.render_one(got.theta), target)
    turned = ImageLoss(poser.turned(target), LossConfig(use_clip=False, crop_size=imitator.resolution))
    assert imitator.refiner.score(turned, theta[None])[0][0] > 0.01  # the turned frame's blur the audience never sees


def test_live_follows_a_file_camera_on_the_emulator(imitator, frames, cal, hand, tmp_path):
    """Frames in, safe moves out: the hand follows every frame within the servos' limits, no tick collides, the
    latency of each target is measured, the log is written, and when the file ends the hand rests on its last pose."""
    updates = []
    log = tmp_path / "live.npz"
    camera = Camera(str(frames), fps=15)
    with ServoSession(calibration=cal) as session:
        result = run_live(imitator, session.bus, cal, camera, LiveConfig(), on_update=updates.append, log_path=log)
    camera.close()
    pb = result.playback
    assert pb.reason == StopReason.COMPLETED, pb.message
    assert result.frames >= 10 and result.updates >= 8, result.summary()
    assert len(result.latencies_s) >= 5 and (result.latencies_s > 0).all() and (result.latencies_s < 1.0).all()
    assert np.isfinite(result.losses).all() and (result.losses < 0.6).all()
    sent = np.asarray(pb.sent)
    assert ((sent >= cal.lower - 1e-9) & (sent <= cal.upper + 1e-9)).all()
    assert not pb.clipped_limit.any() and not pb.clipped_step.any(), "the safety layer had nothing to clip"
    order = [hand.joint_names.index(n) for n in cal.joint_names]
    theta = np.empty_like(sent)
    theta[:, order] = sent
    assert not imitator.refiner.world.in_collision(theta, check=False).any()
    last = np.empty(len(order))
    last[order] = sent[-1]
    assert np.abs(last - result.poses[-1]).max() < 1e-3, "the hand rests on its last target"
    assert log.is_file() and np.load(log)["sent"].shape == sent.shape
    shown = [u for u in updates if u.theta is not None]
    assert shown and all(u.shadow is not None and u.shadow.any() and u.target.any() for u in shown)
    assert result.summary()["latency_p99_ms"] is not None


def test_the_estop_stops_live_within_one_tick(imitator, frames, cal):
    """An e-stop pressed while the hand follows: the player stops before the next tick, holding its torque."""
    ticks, pressed = [], {}
    camera = Camera(str(frames), fps=15, loop=True)
    with ServoSession(calibration=cal) as session:

        def on_update(u) -> None:
            if u.theta is not None and len(ticks) > 20 and "at" not in pressed:
                session.bus.estop(by="the test")
                pressed["at"] = len(ticks)

        result = run_live(imitator, session.bus, cal, camera, LiveConfig(max_seconds=20), on_update=on_update,
                          on_sample=lambda t, c, m: ticks.append(t))  # fmt: skip
    camera.close()
    assert result.playback.reason == StopReason.ESTOP, result.playback.message
    assert len(ticks) - pressed["at"] <= 1, f"{len(ticks) - pressed['at']} ticks after the e-stop"
    assert result.playback.torque == "held" and result.seconds < 15


class StallingSource:
    """A VideoCapture-like source: ``silhouettes`` frames, then ``blanks`` empty walls, then nothing (stalled)."""

    def __init__(self, silhouettes: int, blanks: int):
        self.n, self.silhouettes, self.blanks = 0, silhouettes, blanks

    def isOpened(self) -> bool:
        return True

    def read(self):
        time.sleep(1 / 20)
        self.n += 1
        if self.n <= self.silhouettes:
            return True, silhouette(self.n)
        if self.n <= self.silhouettes + self.blanks:
            return True, np.full((240, 320, 3), 220, np.uint8)
        return False, None

    def release(self) -> None:
        pass


def test_the_hand_holds_and_says_so_when_the_silhouette_vanishes_or_the_camera_stalls(imitator, cal):
    statuses: list[str] = []
    camera = Camera(StallingSource(8, 8), stall_s=0.3)
    with ServoSession(calibration=cal) as session:
        cfg = LiveConfig(max_seconds=3, stall_s=0.3, ramp_speed_rad_s=3.0)
        result = run_live(imitator, session.bus, cal, camera, cfg, on_update=lambda u: statuses.append(u.status))
    camera.close()
    assert result.playback.reason == StopReason.COMPLETED
    assert any(s.startswith("holding: no silhouette") for s in statuses), statuses
    assert any(s.startswith("holding:") and "stalled" in s for s in statuses), statuses
    assert result.updates >= 3 and not result.error
    sent = np.asarray(result.playback.sent)
    assert np.abs(sent[-20:] - sent[-1]).max() < 1e-9, "while nothing new comes the hand holds still"


def test_a_recorded_session_gives_a_recording_and_keyframes_that_plan_reads(imitator, frames, cal, hand, tmp_path):
    rec = LiveRecorder(tmp_path / "rec", hand)
    camera = Camera(str(frames), fps=15)
    with ServoSession(calibration=cal) as session:
        result = run_live(imitator, session.bus, cal, camera, LiveConfig(), on_update=rec.update)
    camera.close()
    files = rec.finish(result)
    assert [f.name for f in files] == ["live.rrd", "keyframes.json"]
    entities = read_recording(files[0])
    for path in ("/images/source", "/images/target", "/images/rendered", "/loss/live"):
        assert path in entities and entities[path]["rows"] >= 3, (path, sorted(entities))
    assert any(p.startswith("/servo/") and p.endswith("/measured") for p in entities)
    kf = load_keyframes(files[1], hand)
    assert 2 <= len(kf.times) <= result.updates and kf.times[0] == 0.0
    assert np.allclose(kf.poses[-1], result.poses[-1])
    doc = json.loads(files[1].read_text())
    assert doc["keyframes"][0]["hold"] and all(np.isfinite(k["loss"]) for k in doc["keyframes"])


def test_stop_from_another_thread_ends_the_session(imitator, frames, cal):
    """The panel's Stop: LiveSession.stop() ends it at the next tick, completed, torque held."""
    got = {}
    camera = Camera(str(frames), fps=15, loop=True)
    with ServoSession(calibration=cal) as session:

        def ready(s) -> None:
            got["s"] = s
            threading.Timer(1.5, s.stop).start()

        result = run_live(imitator, session.bus, cal, camera, LiveConfig(max_seconds=30), session_ready=ready)
    camera.close()
    assert result.playback.reason == StopReason.COMPLETED and result.seconds < 10
    assert not got["s"].ticks.started.is_set() or result.updates >= 1


@pytest.fixture
def small_index(monkeypatch):
    """The verb's imitator builds (and caches) a small index instead of the 200,000-pose one."""
    import studio.imitate.still as still

    monkeypatch.setattr(still, "RetrievalConfig", lambda: SMALL_INDEX)


def test_the_live_verb_runs_a_file_camera_on_the_emulator(in_process, small_index, frames, tmp_path, hand):
    rolled = tmp_path / "cal.yaml"  # a rig calibrated with the hand mounted at roll 30°
    cal = default_calibration(hand)
    save_calibration(cal.__class__(cal.joints, cal.hand_hash, math.radians(30.0)), rolled)
    out = in_process("live", "--camera", frames, "--emulator", "--record", tmp_path / "rec", "--log",
                     tmp_path / "live.npz", "--seconds", 2, "--calibration", rolled, "--quiet")  # fmt: skip
    assert out.returncode == 0, out.stderr
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert summary["stopped"] == "completed" and summary["updates"] >= 3 and summary["latency_p50_ms"] > 0
    assert summary["roll_deg"] == 30.0 and "rolled 30.0° counter-clockwise" in out.stdout  # the calibration's roll
    assert "(the calibration's)" in out.stdout
    assert (tmp_path / "live.npz").is_file() and (tmp_path / "rec" / "live.rrd").is_file()
    kept = load_keyframes(tmp_path / "rec" / "keyframes.json", hand)
    assert len(kept.times) >= 2 and kept.extra["roll_deg"] == 30.0  # a show planned from it is for that mount
    refused = in_process("live", "--camera", frames, "--emulator", "--roll", 0, "--calibration", rolled)
    assert refused.returncode != 0 and "Traceback" not in refused.stderr
    assert "this live session wants the hand mounted at roll +0.0°" in refused.stderr  # --roll says otherwise


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (("--camera", "0"), "give --port PATH (or --emulator"),
        (("--camera", "virtual", "--emulator"), "--camera needs a camera index or a video file"),
        (("--camera", "missing.mp4", "--emulator"), "video file not found: missing.mp4"),
        (("--camera", "0", "--emulator", "--speed-scale", "2"), "--speed-scale"),
    ],
)
def test_the_live_verb_refuses_bad_input_in_one_line(in_process, args, said):
    out = in_process("live", *args)
    assert out.returncode != 0 and said in out.stderr, out.stderr
    assert "Traceback" not in out.stderr and len(out.stderr.strip().splitlines()) <= 3
