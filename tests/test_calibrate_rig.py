"""``calibrate-rig`` end to end on the emulator and the virtual camera, and the calibrated rig in use: collection,
on-the-fly training, the imitator's renderer and the search renderer draw with the measured rig."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from hardware.calibration import load_calibration
from studio.cli.main import main
from studio.learn.captures import load_captures
from studio.learn.checkpoint import model_rig
from studio.learn.config import CollectConfig, TrainerConfig
from studio.project.capture import CaptureConfig
from studio.review.real_vs_sim import ONLY_REAL, ONLY_SIM
from studio.sim.hand import load_hand
from studio.sim.rig_file import RigFileError, measured_rig
from studio.sim.shadow import Rig

TRUE_RIG = (
    "light_distance_m: 2.75\nbackdrop_distance_m: 1.0\nhand_offset_m: [0.01, 0.0, 0.0]\nmount_roll_deg: 4\nfoam_mm: 2\n"
)


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """One short calibration (4 poses, a small fit budget) on the emulator through the virtual camera."""
    folder = tmp_path_factory.mktemp("rigcal")
    (folder / "true.yaml").write_text(TRUE_RIG)
    out = folder / "out"
    # no --timeout: the in-process emulator's default (0.2 s) holds even while the other test worker loads the cores
    argv = ["calibrate-rig", "--camera", "virtual", "--true-rig", str(folder / "true.yaml"), "--emulator",
            "--out", str(out), "--poses", "4", "--max-evals", "250", "--supersample", "2", "--quiet"]  # fmt: skip
    return folder, out, argv


@pytest.mark.slow
def test_calibrate_rig_on_the_virtual_camera_writes_a_measured_rig(calibrated, capsys):
    folder, out, argv = calibrated
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    keys = {"light_distance_m", "backdrop_distance_m", "hand_offset_m", "mount_roll_deg", "foam_mm"}
    assert keys | {"iou_loss_before", "iou_loss_after", "seconds"} <= set(summary)
    assert summary["iou_loss_after"] < 0.5 * summary["iou_loss_before"]
    assert summary["mount_roll_deg"] == pytest.approx(4, abs=1)
    assert summary["foam_mm"] == pytest.approx(2, abs=1)
    hand = load_hand()
    cal = load_calibration(out / "calibration.yaml", hand)  # the servo map, with the measured rig
    assert math.degrees(cal.roll) == pytest.approx(summary["mount_roll_deg"], abs=1e-4)
    assert cal.rig().foam == pytest.approx(summary["foam_mm"] / 1000, abs=1e-6)
    captures = load_captures(out / "captures", hand.hash)
    assert len(captures) == 4 and captures.masks.any(axis=(1, 2)).all()
    # each move between two photographs took its time at the capture's joint speed (2.5 rad/s), not the jog's 0.8
    moved = np.abs(np.diff(captures.theta, axis=0)).max(axis=1).sum() / CaptureConfig().speed_rad_s
    settled = 3 * CaptureConfig().settle_s
    assert moved + settled <= np.diff(captures.t).sum() <= moved + settled + 1.5, (moved, np.diff(captures.t))
    sheet = cv2.cvtColor(cv2.imread(str(out / "compare.png")), cv2.COLOR_BGR2RGB)
    assert sheet.shape[0] >= 4 * 160  # a row per pose
    seen = {c: int(np.all(np.abs(sheet.astype(int) - c) <= 2, axis=-1).sum()) for c in (ONLY_REAL, ONLY_SIM)}
    assert min(seen.values()) > 50, seen  # the "before" overlays show where the nominal rig was off
    # the measured rig trains and renders: unrolled (the roll is the show's), the rest as measured
    rig = measured_rig(out / "calibration.yaml")
    assert rig.roll == 0 and rig.foam == pytest.approx(summary["foam_mm"] / 1000, abs=1e-6)
    assert CollectConfig(rig_file=str(out / "calibration.yaml")).rig().hash not in (Rig().hash,)
    assert TrainerConfig(rig_file=str(out / "calibration.yaml")).rig(128).light[2] == rig.light[2]
    # a second run into the same folder is refused before anything moves
    assert main(argv) == 2
    assert "not empty" in capsys.readouterr().err


def test_the_virtual_camera_needs_its_true_rig_and_the_emulator(tmp_path, capsys):
    out = str(tmp_path / "out")
    assert main(["calibrate-rig", "--camera", "virtual", "--emulator", "--out", out]) == 2
    assert "--true-rig" in capsys.readouterr().err
    (tmp_path / "true.yaml").write_text(TRUE_RIG)
    assert main(["calibrate-rig", "--camera", str(tmp_path / "none.mp4"), "--emulator", "--out", out]) == 2
    err = capsys.readouterr().err
    assert "none.mp4" in err and "Traceback" not in err
    assert main(["calibrate-rig", "--camera", "virtual", "--true-rig", str(tmp_path / "true.yaml"), "--out", out]) == 2
    assert "--port" in capsys.readouterr().err


def test_measured_rig_reads_calibrations_and_rig_files(tmp_path):
    cal = tmp_path / "cal.yaml"
    cal.write_text("format: shadow-studio-calibration\nversion: 1\nrig: {roll_deg: 5.0, light_distance_m: 2.8, "
                   "foam_mm: 1.0}\njoints: {}\n")  # fmt: skip
    rig = measured_rig(cal, Rig(resolution=64))
    assert rig == Rig(light=(0.0, 0.0, 2.8), resolution=64, foam=0.001)  # unrolled, at the base's resolution
    plain = tmp_path / "plain.yaml"
    plain.write_text("format: shadow-studio-calibration\nversion: 1\njoints: {}\n")
    assert measured_rig(plain) == Rig()  # a calibration without a measured rig: nominal
    with pytest.raises(RigFileError, match="not found"):
        measured_rig(tmp_path / "none.yaml")
    assert model_rig({"light": [0, 0, 2.8], "foam": 0.001, "roll": 0.2, "resolution": 256}, 128) == Rig(
        light=(0.0, 0.0, 2.8), resolution=128, foam=0.001
    )
    assert model_rig(None, 64) == Rig(resolution=64)


def test_the_imitator_draws_with_its_model_s_rig():
    from studio.imitate.still import DEFAULT_MODEL, Imitator
    from studio.learn.checkpoint import load_model
    from studio.learn.selfmodel import SelfModel

    model, _ = load_model(DEFAULT_MODEL, SelfModel, device="cpu")
    assert Imitator(model=model).renderer.rig == Rig(resolution=128)  # the shipped model: the nominal rig
    model.trained_rig = Rig(light=(0.0, 0.0, 2.8), foam=0.002, resolution=128).to_dict()
    assert Imitator(model=model).renderer.rig == Rig(light=(0.0, 0.0, 2.8), foam=0.002, resolution=128)


def test_walk_poses_stay_within_a_step_and_out_of_collision():
    from studio.sim.physics import CollisionWorld
    from studio.sim.sampling import walk_poses

    hand = load_hand()
    with CollisionWorld(hand) as world:
        walk = walk_poses(hand, 30, np.random.default_rng(3), 0.2, hand.rest_pose(), world.in_collision)
        assert not world.in_collision(walk).any()
    assert np.abs(np.diff(walk, axis=0)).max() <= 0.2 + 1e-12
    assert (walk >= hand.lower).all() and (walk <= hand.upper).all()
    assert np.abs(walk[-1] - walk[0]).max() > 0.2  # it goes somewhere


@pytest.mark.slow
def test_capture_then_finetune_on_a_held_out_walk(tmp_path, capsys):
    (tmp_path / "true.yaml").write_text(TRUE_RIG)
    base = ["capture", "--camera", "virtual", "--true-rig", str(tmp_path / "true.yaml"), "--emulator", "--quiet",
            "--settle-s", "0.02"]  # fmt: skip
    assert main([*base, "--out", str(tmp_path / "train"), "--pairs", "24"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["pairs"] == 24
    assert main([*base, "--out", str(tmp_path / "held"), "--pairs", "8", "--seed", "1"]) == 0
    capsys.readouterr()
    train = load_captures(tmp_path / "train")
    assert train.resolution == 128 and train.masks.any(axis=(1, 2)).all()
    assert main([*base, "--out", str(tmp_path / "train"), "--pairs", "4", "--seed", "2"]) == 0  # continued
    assert len(load_captures(tmp_path / "train")) == 28
    capsys.readouterr()
    out = tmp_path / "ft.pt"
    argv = ["finetune", "--captures", str(tmp_path / "train"), "--held-out", str(tmp_path / "held"),
            "--out", str(out), "--steps", "20", "--eval-every", "20", "--batch-size", "8", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    result = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert result["pairs_train"] == 28 and result["pairs_held_out"] == 8
    assert result["mae_finetuned"] < result["mae_sim_only"]
