"""``play --camera``: a show played on the emulator while the virtual camera photographs the true rig (light 2.8 m,
mount rolled 2°: not the nominal rig the simulation casts on); every keyframe's captured shadow beside its simulated
shadow and its target, by pixels, in Rerun on show_time; a camera that is absent refuses before the servos move, and
one that dies mid-show does not stop it."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pyarrow as pa
import pytest

from studio.cli.main import main
from studio.review.readback import read_recording
from studio.review.real_vs_sim import ONLY_REAL, ONLY_SIM
from studio.review.sheets import BACKDROP, GAP, SHADOW, display
from studio.sim.shadow import Rig, ShadowRenderer

TRUE_RIG = "light_distance_m: 2.8\nmount_roll_deg: 2.0\ncamera: {width: 480, height: 360}\n"
RES, TILE = 128, 160  # capture resolution; tile of real_vs_sim.png (CLI default)


def poses(hand) -> tuple[np.ndarray, np.ndarray]:
    J = hand.joint_names.index
    qa, qb = hand.rest_pose().copy(), hand.rest_pose().copy()
    qa[[J("wrist"), J("index_pip")]] = (0.3, 0.9)
    qb[[J("wrist"), J("middle_mcp_flex")]] = (-0.3, 0.8)
    return qa, qb


def two_keyframes(hand, folder, targets: bool = True):
    """A 1.2 s show from rest (where the emulator starts: no ramp-in): pose A held at 0.5 s, pose B at 1.2 s; A's
    target is a picture of its nominal shadow (dark on light, beside the show file), B has none."""
    from studio.motion.show import KeyframeMarker, Show, save_show

    qa, qb = poses(hand)
    t = np.arange(0, 1.2 + 1e-9, 1 / 40)

    def ease(x):
        return 0.5 - 0.5 * np.cos(np.pi * np.clip(x, 0, 1))

    q = np.where((t < 0.7)[:, None], qa * ease(t / 0.5)[:, None], qa + (qb - qa) * ease((t - 0.7) / 0.5)[:, None])
    if targets:
        shadow = ShadowRenderer(hand, Rig(resolution=RES)).render_one(qa)
        cv2.imwrite(str(folder / "a_target.png"), display(shadow))
    marks = [KeyframeMarker(0.5, target="a_target.png" if targets else None, hold=True), KeyframeMarker(1.2, hold=True)]
    return save_show(Show.from_samples(hand, t, q, title="two", keyframes=marks), folder / "two.json")


def tile(sheet: np.ndarray, row: int, col: int) -> np.ndarray:
    """Tile ``(row, col)`` of real_vs_sim.png (RGB): rows 6 px apart, tiles 4 px apart."""
    y, x = row * (TILE + 6), col * (TILE + 4)
    return sheet[y + 20 : y + TILE, x : x + TILE]  # below the label


def share(img: np.ndarray, rgb) -> float:
    """Share of ``img``'s pixels within 3 of colour ``rgb``."""
    return float((np.abs(img.astype(int) - rgb).max(-1) <= 3).mean())


@pytest.fixture(scope="module")
def played(tmp_path_factory, hand):
    """``play --dry-run --camera virtual`` once: (its exit code, stdout, the output folder, the .rrd)."""
    folder = tmp_path_factory.mktemp("play_camera")
    (folder / "rig.yaml").write_text(TRUE_RIG)
    show = two_keyframes(hand, folder)
    out, rrd = folder / "captures", folder / "play.rrd"
    args = ["play", str(show), "--dry-run", "--camera", "virtual", "--true-rig", str(folder / "rig.yaml"), "--log",
            str(folder / "play.npz"), "--captures-out", str(out), "--rrd", str(rrd), "--capture-resolution", str(RES),
            "--quiet"]  # fmt: skip
    import contextlib
    import io

    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        code = main(args)
    return code, stdout.getvalue(), out, rrd


def test_every_keyframe_is_captured_and_scored_against_its_simulated_shadow_and_target(played):
    code, out, folder, _ = played
    assert code == 0, out
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["played"] == "completed" and summary["captured"] == 2 and summary["camera_error"] == ""
    a, b = summary["per_keyframe"]
    assert (a["show_time_s"], b["show_time_s"]) == (0.5, 1.2)
    for row in (a, b):  # the true rig is not the nominal one: close, never equal
        assert 0.01 < row["captured_vs_simulated"] < 0.25, row
        assert row["show_time_s"] < row["frame_show_time_s"] < row["show_time_s"] + 0.4, row
        assert (folder / f"k{row['keyframe']}_captured.png").is_file() and row["error"] == ""
    assert a["simulated_vs_target"] < 0.03 and 0.0 < a["captured_vs_target"] < 0.25  # the target is A's nominal shadow
    assert b["captured_vs_target"] is None and b["simulated_vs_target"] is None  # B has no target
    table = [line.split() for line in out.splitlines() if line.split()[:2] in (["0", "0.50"], ["1", "1.20"])]
    assert (
        len(table) == 2
        and table[1][2:4] == ["-", "-"]
        and float(table[0][4]) == pytest.approx(a["captured_vs_simulated"], abs=1e-4)
    )
    captured = cv2.imread(str(folder / "k0_captured.png"), cv2.IMREAD_GRAYSCALE)
    assert captured.shape == (RES, RES) and 0.02 < (captured < 100).mean() < 0.5  # a shadow, dark on light


def test_real_vs_sim_png_shows_target_captured_simulated_and_their_overlay(played):
    _, _, folder, _ = played
    sheet = cv2.cvtColor(cv2.imread(str(folder / "real_vs_sim.png")), cv2.COLOR_BGR2RGB)
    assert sheet.shape == (2 * TILE + 6, 4 * TILE + 12, 3)
    for row in (0, 1):
        captured, simulated, both = (tile(sheet, row, c) for c in (1, 2, 3))
        for img in (captured, simulated):  # dark shadow on the light backdrop, nothing else
            assert 0.02 < share(img, SHADOW) < 0.5 and share(img, SHADOW) + share(img, BACKDROP) > 0.97
        # captured over simulated: both in shadow dark, the rig's error in orange (camera only) and blue (model only)
        assert share(both, SHADOW) > 0.02 and share(both, BACKDROP) > 0.4
        assert share(both, ONLY_REAL) > 0.001 and share(both, ONLY_SIM) > 0.0005
        assert share(both, ONLY_REAL) + share(both, ONLY_SIM) < 0.5 * share(both, SHADOW)
    assert 0.02 < share(tile(sheet, 0, 0), SHADOW) < 0.5  # A's target
    assert share(tile(sheet, 1, 0), GAP) > 0.95  # B has none: a grey tile


def test_the_recording_has_each_keyframes_images_and_losses_on_show_time(played):
    _, out, _, rrd = played
    rec = read_recording(rrd)
    summary = json.loads(out.strip().splitlines()[-1])
    for entity in ("/images/captured", "/images/simulated", "/images/real_vs_sim"):
        rows = []
        for batch in rec[entity]["batches"]:
            if "show_time" in batch.schema.names and "Image:buffer" in batch.schema.names:
                times = batch.column("show_time").cast(pa.int64()).to_pylist()
                rows += list(zip(times, batch.column("Image:buffer").to_pylist()))
        assert [t for t, _ in sorted(rows)] == [500_000_000, 1_200_000_000], entity
        for _, buffer in rows:
            pixels = np.asarray(buffer[0] if isinstance(buffer[0], list) else buffer, dtype=np.uint8).ravel()
            assert pixels.size in (RES * RES, RES * RES * 3), entity
            assert 0.02 < (pixels < 100).mean() < 0.5, entity  # dark shadow on a light backdrop
    loss = "/loss/capture/captured_vs_simulated"
    assert "show_time" in rec[loss]["timelines"] and "/loss/capture/captured_vs_target" in rec
    got = []
    for batch in rec[loss]["batches"]:
        got += [v[0] for v in batch.column("Scalars:scalars").to_pylist()]
    want = [r["captured_vs_simulated"] for r in summary["per_keyframe"]]
    assert got == pytest.approx(want, abs=1e-4)
    assert "show_time" in rec["/servo/wrist/commanded"]["timelines"]  # the playback beside them


def test_a_camera_that_is_absent_refuses_before_the_servos_move(hand, tmp_path, capsys):
    from hardware.emulator import ServoEmulator

    show = two_keyframes(hand, tmp_path, targets=False)
    with ServoEmulator(range(1, 22)) as emu:
        before = emu.positions()
        code = main(["play", str(show), "--port", emu.port, "--camera", str(tmp_path / "no_such_clip.mp4"), "--log",
                     str(tmp_path / "play.npz"), "--quiet"])  # fmt: skip
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 2
        clip = tmp_path / "no_such_clip.mp4"
        assert err[-1] == (f"shadow-studio play: error: no picture from video file {clip} (video file not found: "
                           f"{clip}): the show was not played")  # fmt: skip
        assert not any("Traceback" in line for line in err)
        assert emu.positions() == before and not any(emu.servo(i).torque for i in range(1, 22))  # never moved
    assert not (tmp_path / "play.npz").exists()


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["--dry-run", "--true-rig", "rig.yaml"], "--true-rig goes with --camera"),
        (["--dry-run", "--rrd", "a.rrd"], "--rrd goes with --camera"),
        (["--port", "/dev/no-such", "--camera", "virtual", "--true-rig", "rig.yaml"], "add --dry-run and --true-rig"),
        (["--dry-run", "--camera", "virtual"], "add --dry-run and --true-rig"),
        (["--dry-run", "--camera", "0", "--true-rig", "rig.yaml"], "use it with --camera virtual"),
    ],
)
def test_camera_flags_that_do_not_fit_are_one_line(hand, tmp_path, capsys, extra, said):
    show = two_keyframes(hand, tmp_path, targets=False)
    assert main(["play", str(show), "--log", str(tmp_path / "p.npz"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and said in err[0], err


def test_a_camera_that_dies_mid_show_does_not_stop_it(hand, tmp_path):
    """The camera fails after the first keyframe: the show completes, the first keyframe is scored, the others say
    why they have no picture, and the result names the camera's failure."""
    from hardware.calibration import load_calibration
    from hardware.camera import Camera
    from hardware.player import Player
    from hardware.session import ServoSession
    from hardware.virtual_camera import VirtualCamera, emulator_angles
    from studio.motion.show import load_show
    from studio.project.show_capture import ShowCaptureConfig, play_with_camera
    from studio.sim.photo import CameraModel

    show = load_show(two_keyframes(hand, tmp_path, targets=False))
    cal = load_calibration(None, hand)

    class Dying(VirtualCamera):
        def read(self):
            if dead:
                raise OSError("the USB cable came out")
            return super().read()

    dead = False

    def kill_after_first(t, commanded, measured):
        nonlocal dead
        dead = dead or t > 0.95  # between the keyframes (0.5 s, 1.2 s), after A's picture

    with ServoSession(calibration=cal) as session:
        small = CameraModel(width=480, height=360)
        virtual = Dying(emulator_angles(session.emulator, cal), Rig(light=(0, 0, 2.8)), small)
        with Camera(virtual) as camera:
            player = Player(session.bus, cal, on_sample=kill_after_first)
            done = play_with_camera(player, show, camera, ShowCaptureConfig(resolution=RES, frame_timeout_s=0.5))
    assert done.playback.ok and player.on_sample is kill_after_first  # the player's own hook is given back
    a, b = done.captures
    assert a.captured is not None and a.error == "" and math.isfinite(a.losses["captured_vs_simulated"])
    assert b.captured is None and "no picture" in b.error and "USB cable" in b.error
    assert "USB cable" in done.camera_error and math.isnan(b.losses["captured_vs_simulated"])
    assert np.abs(a.measured - a.commanded).max() < 0.05  # the read-backs at the frame's time: the hand held A


def test_the_simulated_shadow_is_the_pose_the_player_sends_stopped_at_the_soft_limits(tmp_path, hand):
    """A calibration whose wrist stops at 0 rad while the show's pose A asks 0.3 rad: `play` says so before moving,
    the emulator's hand holds the wrist at its limit, and the simulated shadow beside the photograph is that pose's
    (so the camera and the simulation agree), not the show's, whose own shadow is its target."""
    from dataclasses import replace

    from hardware.calibration import load_calibration, save_calibration
    from studio.project.show_capture_data import aligned_iou_loss

    (tmp_path / "rig.yaml").write_text("camera: {width: 480, height: 360}\n")  # the nominal rig: no rig error
    show = two_keyframes(hand, tmp_path)
    cal = load_calibration(None, hand)
    save_calibration(replace(cal, joints=tuple(replace(j, upper=0.0) if j.name == "wrist" else j for j in cal.joints)),
                     tmp_path / "narrow.yaml")  # fmt: skip
    out = tmp_path / "captures"
    args = ["play", str(show), "--dry-run", "--camera", "virtual", "--true-rig", str(tmp_path / "rig.yaml"),
            "--calibration", str(tmp_path / "narrow.yaml"), "--captures-out", str(out), "--capture-resolution",
            str(RES), "--quiet"]  # fmt: skip
    import contextlib
    import io

    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert main(args) == 0
    lines = stdout.getvalue().strip().splitlines()
    assert any(x.startswith("note: the show asks 1 joint beyond the calibration's soft limits (wrist by 17.2°)")
               for x in lines), lines  # fmt: skip
    a = json.loads(lines[-1])["per_keyframe"][0]
    qa = poses(hand)[0]
    held = qa.copy()
    held[hand.joint_names.index("wrist")] = 0.0
    renderer = ShadowRenderer(hand, Rig(resolution=RES))
    simulated = (cv2.imread(str(out / "k0_simulated.png"), cv2.IMREAD_GRAYSCALE) < 100).astype(np.uint8)
    captured = (cv2.imread(str(out / "k0_captured.png"), cv2.IMREAD_GRAYSCALE) < 100).astype(np.uint8)
    assert aligned_iou_loss(simulated, renderer.render_one(held)) < 0.01  # the pose as sent, not as the show asks
    assert a["captured_vs_simulated"] < 0.03  # the camera sees what the simulation casts
    assert a["simulated_vs_target"] > 0.1 and a["captured_vs_target"] > 0.1  # the show's pose cast its target
    assert aligned_iou_loss(captured, renderer.render_one(qa)) > 3 * a["captured_vs_simulated"]
