"""Search + refinement on targets rendered from known poses; refinement never collides; review and CLI outputs."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import torch

from studio.errors import Progress
from studio.imitate.config import CPU_SEARCH, ImitateConfig, LossConfig, RefineConfig, SearchConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner
from studio.imitate.search import gradient_search, initial_poses
from studio.imitate.still import DEFAULT_MODEL, Imitator
from studio.learn.selfmodel import SelfModel, SelfModelConfig, load_selfmodel
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer, iou
from studio.targets.images import SAMPLE_DIR

if not DEFAULT_MODEL.is_file():
    pytest.skip(f"shipped self-model missing: {DEFAULT_MODEL}", allow_module_level=True)


@pytest.fixture(scope="module")
def imitator(hand):
    torch.set_num_threads(1)
    model, _ = load_selfmodel(DEFAULT_MODEL, hand, device="cpu")
    with Imitator(model, loss_cfg=LossConfig(use_clip=False, crop_size=model.cfg.resolution)) as imitator:
        yield imitator


def free_poses(hand, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    with CollisionWorld(hand) as world:
        out = []
        while len(out) < n:
            q = sample_poses(hand, 1, rng)[0][0]
            if not world.in_collision(q)[0]:
                out.append(q)
    return np.stack(out)


@pytest.mark.slow
def test_search_and_refinement_recover_a_rendered_pose(imitator, hand):
    scores = []
    for q in free_poses(hand, 3, seed=21):
        target = imitator.renderer.render_one(q)
        result = imitator.imitate(target)
        assert result.collision_free
        scores.append(float(iou(result.shadow, target)))
    # three uniformly random (tangled) poses: on average the shadow is recovered to IoU ≥ 0.9
    assert np.mean(scores) >= 0.9 and min(scores) >= 0.85, scores


@pytest.mark.slow
def test_search_lowers_the_self_model_loss(imitator, hand):
    target = imitator.renderer.render_one(free_poses(hand, 1, seed=5)[0])
    loss_fn = imitator.loss_fn(target)
    res = gradient_search(imitator.model, loss_fn, replace(CPU_SEARCH, iterations=60, log_every=5))
    start = res.curve[0][1]
    assert res.loss < start and res.curve[-1][1] <= start
    assert res.batch_theta.shape == (CPU_SEARCH.batch, 21)
    assert np.all(res.batch_theta >= hand.lower - 1e-5) and np.all(res.batch_theta <= hand.upper + 1e-5)
    assert res.loss == pytest.approx(res.batch_loss.min(), rel=1e-5)


def test_initial_poses_respect_limits_and_include_rest(hand):
    cfg = SearchConfig(batch=16)
    th = initial_poses(hand, cfg)
    assert th.shape == (16, 21) and np.allclose(th[0], hand.rest_pose())
    near = initial_poses(hand, cfg, init=hand.rest_pose())
    assert np.all(near >= hand.lower) and np.all(near <= hand.upper)
    assert np.abs(near - hand.rest_pose()).max() < 0.3


@pytest.mark.slow
def test_cancel_stops_search_early(hand):
    import threading

    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    target = ShadowRenderer(hand, Rig(resolution=32)).render_one(hand.rest_pose())
    cancel = threading.Event()
    seen = []

    def progress(p: Progress):
        assert p.stage == "search" and p.total == 100
        seen.append(p.step)
        cancel.set()

    loss_fn = ImageLoss(target, LossConfig(use_clip=False, crop_size=32))
    cfg = SearchConfig(batch=4, iterations=100, log_every=1)
    res = gradient_search(model, loss_fn, cfg, progress=progress, cancel=cancel)
    assert res.cancelled and res.iterations == 1 and seen == [1]


def colliding_start(hand, seed: int) -> np.ndarray:
    """Middle finger swung through the index, ring finger spread into the little finger: deep self-collision."""
    q = hand.rest_pose()
    q[hand.joint_names.index("middle_mcp_abd")] = np.radians(-15 - 10 * seed)
    q[hand.joint_names.index("ring_mcp_abd")] = np.random.default_rng(seed).uniform(0.3, 0.9)
    return q


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_refinement_climbs_out_of_collision(hand, seed):
    """From a badly colliding pose the chains climb out of collision: the answer is a free pose within the limits."""
    renderer = ShadowRenderer(hand, Rig(resolution=64))
    start = colliding_start(hand, seed)
    target = renderer.render_one(free_poses(hand, 1, seed=seed)[0])
    loss_fn = ImageLoss(target, LossConfig(use_clip=False, crop_size=64))
    with Refiner(renderer) as refiner:
        assert refiner.world.in_collision(start)[0]
        res = refiner.refine(loss_fn, start, RefineConfig(steps=150, seed=seed))
        assert res.start_collides and res.collision_free, res.message
        assert not refiner.world.in_collision(res.theta)[0]
        assert res.loss == pytest.approx(refiner.score(loss_fn, res.theta[None])[0][0])
    assert np.isfinite(res.loss) and "collision-free pose found" in res.message
    assert np.all(res.theta >= hand.lower) and np.all(res.theta <= hand.upper)


def test_refinement_says_when_no_collision_free_pose_was_found(hand):
    """One chain and no proposals: the only pose visited is the colliding start, so no free pose can be found."""
    renderer = ShadowRenderer(hand, Rig(resolution=64))
    start = colliding_start(hand, 0)
    loss_fn = ImageLoss(renderer.render_one(hand.rest_pose()), LossConfig(use_clip=False, crop_size=64))
    with Refiner(renderer) as refiner:
        res = refiner.refine(loss_fn, start, RefineConfig(restarts=1, steps=0))
    assert res.start_collides and not res.collision_free
    assert res.loss == float("inf") and np.isfinite(res.start_loss)
    assert "no collision-free pose" in res.message
    assert np.array_equal(res.theta, start)  # the (colliding) start comes back, as documented


def test_refiner_and_imitator_close_their_collision_world(hand):
    import pybullet as p

    from studio.errors import ClosedError

    renderer = ShadowRenderer(hand, Rig(resolution=32))
    loss_fn = ImageLoss(renderer.render_one(hand.rest_pose()), LossConfig(use_clip=False, crop_size=32))
    with Refiner(renderer) as refiner:
        client = refiner.world.client
        assert p.isConnected(client)
    assert not p.isConnected(client)
    refiner.close()  # closing twice is fine
    with pytest.raises(ClosedError, match="Refiner was closed"):
        refiner.refine(loss_fn, hand.rest_pose(), RefineConfig(steps=1))
    with CollisionWorld(hand) as world:  # a world passed in stays the caller's
        with Refiner(renderer, world):
            pass
        assert p.isConnected(world.client)
    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    with Imitator(model, loss_cfg=LossConfig(use_clip=False, crop_size=32)) as imitator:
        client = imitator.refiner.world.client
        assert p.isConnected(client)
    assert not p.isConnected(client)
    imitator.close()
    with pytest.raises(ClosedError, match="Imitator was closed"):
        imitator.imitate(np.zeros((32, 32), np.uint8))


def test_refinement_never_worsens_a_free_start(hand):
    renderer = ShadowRenderer(hand, Rig(resolution=64))
    q_target, q_start = free_poses(hand, 2, seed=8)
    loss_fn = ImageLoss(renderer.render_one(q_target), LossConfig(use_clip=False, crop_size=64))
    with Refiner(renderer) as refiner:
        res = refiner.refine(loss_fn, q_start, RefineConfig(steps=100))
    assert res.collision_free and res.loss <= res.start_loss
    assert [b for _, b in res.curve] == sorted((b for _, b in res.curve), reverse=True)


def _imitate_cli(*args: str, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "studio.cli", "imitate", *args], capture_output=True, text=True,
                          timeout=600, **kw)  # fmt: skip


@pytest.mark.slow
def test_imitate_cli_writes_the_files_of_every_source(tmp_path):
    """A still through ``imitate``: a one-source project, and the files ``imitate-video`` writes; the target's
    opening is its expressive region, the keyframes file plans to a show holding the pose."""
    from studio.motion.show import load_show
    from studio.targets.images import DEFAULT_TARGET

    out = tmp_path / "out"
    proc = _imitate_cli(str(DEFAULT_TARGET), "--out", str(out), "--no-clip", "--quiet", "--search-iterations", "5",
                        "--refine-steps", "60")  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["collision_free"] is True and summary["no_clip"] is True and summary["frames"] == 1
    for name in ("keyframes.json", "show.json", "contact.png", "side_by_side.mp4", "review.rrd"):
        assert (out / name).is_file(), name
    doc = json.loads((out / "keyframes.json").read_text())
    (pose,) = doc["poses"]
    assert len(pose["pose"]) == 21 and doc["provenance"]["no_clip"] is True and doc["complete"]
    assert pose["loss"]["clip"] is None  # not computed: recorded as null, never as a fake 0
    assert pose["loss"]["exp_iou"] is not None and 0 <= pose["loss"]["exp_iou"] <= 1  # the "o"'s opening
    assert pose["loss"]["total"] == pytest.approx(pose["loss"]["base"] + pose["loss"]["expr"])
    assert [k["t"] for k in doc["keyframes"]] == [0.0, 2.0]  # reached at once, held 2 s (--still-hold-s)
    show = out / "replanned.json"
    planned = subprocess.run([sys.executable, "-m", "studio.cli", "plan", str(out / "keyframes.json"), "--out",
                              str(show)], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert planned.returncode == 0 and "Traceback" not in planned.stderr, planned.stderr
    loaded = load_show(show)
    expected = [pose["pose"][n] for n in loaded.joint_names]
    assert loaded.duration == pytest.approx(2.0) and np.allclose(loaded.positions, expected, atol=1e-9)


@pytest.mark.slow
def test_imitate_cli_errors(tmp_path, in_process):
    bad = tmp_path / "empty.png"
    import cv2

    cv2.imwrite(str(bad), np.zeros((32, 32), np.uint8))
    for i, (args, message) in enumerate((
        ((str(tmp_path / "absent.png"), "--no-clip"), "not found"),
        ((str(bad), "--no-clip"), "one flat grey level"),
        ((str(bad),), "one flat grey level"),  # a bad target is named before CLIP weights are looked for
        ((str(bad), "--model", str(tmp_path / "none.pt"), "--no-clip"), "checkpoint not found"),
    )):  # fmt: skip
        argv = ["imitate", *args, "--out", str(tmp_path / "o")]
        proc = (subprocess.run([sys.executable, "-m", "studio.cli", *argv], capture_output=True, text=True, timeout=300)
                if i == 0 else in_process(*argv))  # one real start, the rest in this process  # fmt: skip
        assert proc.returncode == 2 and message in proc.stderr.lower() and "Traceback" not in proc.stderr, proc.stderr


def _tiny_imitator(hand, **kw) -> tuple[Imitator, np.ndarray]:
    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    kw.setdefault("config", ImitateConfig(retrieve=False))  # no index for this toy model (tests/test_retrieval.py)
    imitator = Imitator(model, loss_cfg=LossConfig(use_clip=False, crop_size=32), **kw)
    return imitator, imitator.renderer.render_one(free_poses(hand, 1, seed=2)[0])


def test_cancel_before_refinement_returns_a_flagged_result(hand):
    """Cancelled before refinement started: the searched pose comes back flagged, not an AttributeError on None."""
    import threading

    small = dict(
        search=SearchConfig(batch=4, iterations=50, log_every=1), refine=RefineConfig(steps=10, restarts=2, log_every=1)
    )
    imitator, target = _tiny_imitator(hand, **small)
    with imitator:
        cancel = threading.Event()
        cancel.set()
        result = imitator.imitate(target, cancel=cancel)
        assert result.cancelled and result.search.cancelled and result.search.iterations == 0
        assert result.refine is None and np.array_equal(result.theta, result.unrefined_theta)
        assert np.isfinite(result.loss["total"])
        # cancelled during the search: still no refinement, still flagged
        cancel.clear()
        result = imitator.imitate(target, progress=lambda p: p.step >= 3 and cancel.set(), cancel=cancel)
        assert result.cancelled and result.search.iterations == 3 and result.refine is None
        # cancelled during refinement: the best free pose so far, flagged
        cancel.clear()
        result = imitator.imitate(target, progress=lambda p: p.stage == "refine" and cancel.set(),
                                  cancel=cancel)  # fmt: skip
        assert result.cancelled and result.refine is not None and result.refine.cancelled
        assert not imitator.imitate(target).cancelled


def test_zero_candidates_is_refused(hand):
    from studio.imitate.candidates import distinct_best

    with pytest.raises(ValueError, match="candidates must be ≥ 1"):
        ImitateConfig(candidates=0)
    theta = np.random.default_rng(0).uniform(-1, 1, (6, 21))
    assert distinct_best(theta, np.arange(6.0), 0) == []
    assert len(distinct_best(theta, np.arange(6.0), 2)) == 2


@pytest.mark.slow
def test_imitate_threshold_flags_reach_the_target(tmp_path):
    import cv2

    from studio.cli.main import build_parser
    from studio.cli.source_flags import still_config_from_args
    from studio.targets.images import TargetConfig

    def cfg(*flags: str) -> TargetConfig:
        return still_config_from_args(build_parser().parse_args(["imitate", "t.png", "--out", "o", *flags]))

    assert cfg() == TargetConfig()  # 25, or Otsu by itself where the border is not dark
    assert cfg("--otsu").threshold is None
    assert cfg("--still-threshold", "25") == TargetConfig(threshold=25.0, auto_otsu=False)  # asked for: always used
    assert cfg("--otsu", "--still-pocket-reach", "0") == TargetConfig(threshold=None, pocket_reach=0.0)  # both kept
    grey = np.full((96, 96), 170, np.uint8)  # a light-grey wall (shadowness 85) with a dark disc
    cv2.circle(grey, (48, 48), 30, 30, -1)
    path = tmp_path / "grey_wall.png"
    cv2.imwrite(str(path), grey)
    fixed = _imitate_cli(str(path), "--out", str(tmp_path / "o"), "--no-clip", "--still-threshold", "25")
    assert fixed.returncode == 2 and "Traceback" not in fixed.stderr, fixed.stderr
    assert fixed.stderr.strip().splitlines() == [
        f"shadow-studio imitate: error: every pixel is shadow (no backdrop, check the polarity/threshold): {path}"
    ]


@pytest.mark.slow
def test_ctrl_c_stops_imitate_and_the_same_command_resumes(tmp_path):
    """The first Ctrl-C cancels the search: one line says so, exit code 130, the project stays (nothing finished)."""
    import os
    import signal
    import time

    out = tmp_path / "o"
    proc = subprocess.Popen(
        [sys.executable, "-m", "studio.cli", "imitate", str(SAMPLE_DIR / "asl_v.jpeg"), "--out", str(out),
         "--no-clip", "--search-iterations", "100000", "--refine-steps", "20"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE,
    )  # fmt: skip
    seen, deadline = b"", time.monotonic() + 300
    while b"search" not in seen and time.monotonic() < deadline:  # the search's progress bar: it is running
        chunk = os.read(proc.stderr.fileno(), 4096)
        if not chunk:
            break
        seen += chunk
    assert b"search" in seen, seen.decode(errors="replace")
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=300)
    stderr = (seen + stderr).decode(errors="replace")
    assert proc.returncode == 130 and "Traceback" not in stderr, stderr
    assert stderr.strip().splitlines()[-1] == (
        f"shadow-studio imitate: cancelled: the finished keyframes are kept in {out / 'asl_v.shadow'}; the same "
        "command resumes"
    )
    summary = json.loads(stdout.decode().strip().splitlines()[-1])
    doc = json.loads((out / "keyframes.json").read_text())
    assert summary["cancelled"] is True and not doc["complete"] and doc["poses"] == []
    assert (out / "asl_v.shadow" / "project.json").is_file()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_self_model_and_clip_score_cpu_renders(hand):
    """CLIP on the self-model's device (CUDA): search on CUDA, refinement feeds its CPU renders to the encoder."""
    from studio.imitate.clip_loss import tiny_clip

    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    model = model.to("cuda")
    clip = tiny_clip().to("cuda")
    with Imitator(model, clip=clip, search=SearchConfig(batch=4, iterations=5), refine=RefineConfig(steps=5)) as im:
        target = im.renderer.render_one(free_poses(hand, 1, seed=2)[0])
        loss_fn = im.loss_fn(target)
        poses = free_poses(hand, 3, seed=4)
        total, comps = im.refiner.score(loss_fn, poses)
        assert total.shape == (3,) and np.isfinite(comps["clip"]).all()
        cpu_loss = ImageLoss(target, im.loss_cfg, tiny_clip())
        cpu_total, _ = Refiner(im.renderer).score(cpu_loss, poses)
        assert total == pytest.approx(cpu_total, abs=1e-4)
        result = im.imitate(target)
        assert np.isfinite(result.loss["clip"])
        # CPU images under a CUDA encoder (what evaluate's baselines and table score do): scored, on the CPU
        cpu_total2, comps2 = loss_fn(torch.from_numpy(im.renderer.render(poses, check=False)).float())
        assert comps2["clip"].device.type == "cpu" and cpu_total2.numpy() == pytest.approx(cpu_total, abs=1e-4)
