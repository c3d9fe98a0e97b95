"""Search + refinement on targets rendered from known poses; refinement never collides; review and CLI outputs."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import torch

from studio.imitate.losses import ImageLoss, LossConfig
from studio.imitate.refine import RefineConfig, Refiner
from studio.imitate.search import CPU_SEARCH, SearchConfig, gradient_search, initial_poses
from studio.imitate.still import DEFAULT_MODEL, Imitator
from studio.imitate.targets import SAMPLE_DIR
from studio.learn.selfmodel import SelfModel, SelfModelConfig, load_selfmodel
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses
from studio.sim.shadow import Rig, ShadowRenderer, iou

if not DEFAULT_MODEL.is_file():
    pytest.skip(f"shipped self-model missing: {DEFAULT_MODEL}", allow_module_level=True)


@pytest.fixture(scope="module")
def imitator(hand):
    torch.set_num_threads(1)
    model, _ = load_selfmodel(DEFAULT_MODEL, hand, device="cpu")
    return Imitator(model, loss_cfg=LossConfig(use_clip=False, crop_size=model.cfg.resolution))


def free_poses(hand, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    with CollisionWorld(hand) as world:
        out = []
        while len(out) < n:
            q = sample_poses(hand, 1, rng)[0][0]
            if not world.in_collision(q)[0]:
                out.append(q)
    return np.stack(out)


def test_search_and_refinement_recover_a_rendered_pose(imitator, hand):
    scores = []
    for q in free_poses(hand, 3, seed=21):
        target = imitator.renderer.render_one(q)
        result = imitator.imitate(target)
        assert result.collision_free
        scores.append(float(iou(result.shadow, target)))
    # three uniformly random (tangled) poses: on average the shadow is recovered to IoU ≥ 0.9
    assert np.mean(scores) >= 0.9 and min(scores) >= 0.85, scores


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


def test_cancel_stops_search_early(hand):
    import threading

    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    target = ShadowRenderer(hand, Rig(resolution=32)).render_one(hand.rest_pose())
    cancel = threading.Event()
    seen = []

    def progress(step, total, best):
        seen.append(step)
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


def test_review_recording_reads_back(imitator, hand, tmp_path):
    from studio.review.rerun import log_imitation, read_recording, scalar_series

    imitator_fast = Imitator(imitator.model, loss_cfg=imitator.loss_cfg,
                             search=replace(CPU_SEARCH, iterations=30), refine=RefineConfig(steps=100))  # fmt: skip
    target = imitator.renderer.render_one(free_poses(hand, 1, seed=3)[0])
    result = imitator_fast.imitate(target)
    path = log_imitation(tmp_path / "review.rrd", result, hand, name="t")
    rec = read_recording(path)
    for entity in ("/images/target", "/images/self_model", "/images/rendered", "/images/overlay"):
        assert entity in rec, sorted(rec)
    assert rec["/images/target"]["static"]
    search = scalar_series(rec, "/loss/search/best")
    assert [t for t, _ in search] == [s for s, _, _ in result.search.curve]
    # refinement continues the timeline after the search; steps before a first collision-free pose have no value
    n = result.search.iterations
    finite = [(n + s, b) for s, b in result.refine.curve if np.isfinite(b)]
    got = scalar_series(rec, "/loss/refine/best")
    assert finite and [t for t, _ in got] == [t for t, _ in finite]
    assert [b for _, b in got] == pytest.approx([b for _, b in finite])
    shells = [e for e in rec if e.endswith(("/shell/capsules", "/shell/boxes"))]
    assert len(shells) == 22 and all(rec[e]["static"] for e in shells)  # one shell per link, static
    assert "/world/hand/forearm/palm/index_knuckle/index_proximal" in rec
    assert "opt_step" in rec["/world/hand/forearm/palm"]["timelines"]


def test_imitate_cli_writes_everything(tmp_path):
    target = SAMPLE_DIR / "asl_v.jpeg"
    out = tmp_path / "out"
    proc = subprocess.run(
        [sys.executable, "-m", "studio.cli", "imitate", str(target), "--out", str(out), "--no-clip", "--quiet",
         "--search-iters", "40", "--refine-steps", "100"],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout.strip().splitlines()[-1])
    assert summary["collision_free"] is True and summary["no_clip"] is True
    assert 0 <= summary["iou_loss"] <= 1 and summary["total"] > 0 and summary["seconds"] > 0
    for name in ("pose.json", "shadow.png", "compare.png", "review.rrd"):
        assert (out / name).is_file(), name
    pose = json.loads((out / "pose.json").read_text())
    assert len(pose["pose"]) == 21 and pose["provenance"]["no_clip"] is True
    assert pose["loss"]["clip"] is None  # not computed: recorded as null, never as a fake 0
    # pose.json is a keyframes file: plan a show from it (rest pose at t = 0 → this pose at t = 2 s)
    assert pose["keyframes"][0]["t"] == 2.0 and pose["keyframes"][0]["pose"] == pose["pose"]
    show = out / "show.json"
    planned = subprocess.run([sys.executable, "-m", "studio.cli", "plan", str(out / "pose.json"), "--out", str(show)],
                             capture_output=True, text=True, timeout=300)  # fmt: skip
    assert planned.returncode == 0, planned.stderr
    from studio.motion.show import load_show

    loaded = load_show(show)
    assert np.allclose(loaded.positions[-1], [pose["pose"][n] for n in loaded.joint_names], atol=1e-9)


def test_imitate_cli_errors(tmp_path):
    bad = tmp_path / "empty.png"
    import cv2

    cv2.imwrite(str(bad), np.zeros((32, 32), np.uint8))
    for args, message in (
        ((str(tmp_path / "absent.png"),), "not found"),
        ((str(bad),), "no shadow"),
        ((str(bad), "--model", str(tmp_path / "none.pt")), "checkpoint not found"),
    ):
        proc = subprocess.run([sys.executable, "-m", "studio.cli", "imitate", *args, "--out", str(tmp_path / "o"),
                               "--no-clip"], capture_output=True, text=True, timeout=300)  # fmt: skip
        assert proc.returncode == 2 and message in proc.stderr.lower() and "Traceback" not in proc.stderr, proc.stderr
