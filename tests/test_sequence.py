"""Sequences: inherited initialisation keeps consecutive poses close, the temporal term in refinement, transition
success at each threshold's boundary, cancel with partial results, poses within limits and collision-free."""

from __future__ import annotations

import math
import threading
import time
from dataclasses import replace

import numpy as np
import pytest
import torch

from studio.errors import ClosedError, Progress
from studio.imitate.config import CPU_SEQUENCE, PAPER_SEQUENCE, LossConfig, RefineConfig, SearchConfig, SequenceConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.sequence import SequenceImitator
from studio.imitate.still import DEFAULT_MODEL
from studio.imitate.transitions import TransitionConfig, transition_success
from studio.learn.selfmodel import load_selfmodel
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses
from studio.targets.expressive import expressive_masks
from studio.targets.keyframes import keyframe_targets

TINY = SequenceConfig(
    first=SearchConfig(batch=16, iterations=40, lr=0.08),
    next=SearchConfig(batch=8, iterations=20, lr=0.08),
    refine=RefineConfig(restarts=4, steps=40),
    candidates=1,
)


def free_poses(hand, n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    with CollisionWorld(hand) as world:
        out = []
        while len(out) < n:
            q = sample_poses(hand, 1, rng)[0][0]
            if not world.in_collision(q)[0]:
                out.append(q)
    return np.stack(out)


# --- transition success on hand-made pose pairs (pure arithmetic, no model) -------------------------------------


def pair(delta: np.ndarray) -> np.ndarray:
    return np.stack([np.zeros(21), np.asarray(delta, dtype=np.float64)])


def test_transition_thresholds_are_the_papers():
    cfg = TransitionConfig()
    assert (cfg.max_total, cfg.max_mean_step, cfg.max_step, cfg.total) == (0.35, 0.85, 2.00, "base")
    with pytest.raises(ValueError):
        TransitionConfig(total="everything")
    with pytest.raises(ValueError):
        TransitionConfig(max_step=-1)


def test_transition_total_boundary():
    thetas = pair(np.full(21, 0.1))
    for totals, expected in [
        ([0.35, 0.35], True),  # inclusive
        ([0.35, 0.35 + 1e-9], False),
        ([0.35 + 1e-9, 0.2], False),  # either endpoint fails the transition
        ([0.2, math.nan], False),  # a total not computed never passes
    ]:
        ok, rep = transition_success(thetas, np.array(totals))
        assert ok.tolist() == [expected], totals
        assert rep.mean_ok.all() and rep.max_ok.all()


def test_transition_mean_step_boundary():
    cfg = TransitionConfig()
    for step, expected in [(0.85 - 1e-9, True), (0.85 + 1e-9, False), (0.9, False)]:
        ok, rep = transition_success(pair(np.full(21, step)), np.array([0.1, 0.1]), cfg)
        assert rep.mean_step[0] == pytest.approx(step, abs=1e-12) and rep.max_ok[0]  # only the mean can fail
        assert ok.tolist() == [expected] and rep.mean_ok.tolist() == [expected], step
    # the sign of a step does not matter
    assert transition_success(pair(np.full(21, -0.84)), np.array([0.1, 0.1]))[0].tolist() == [True]


def test_transition_max_step_boundary():
    for step, expected in [(2.0, True), (2.0 + 1e-9, False), (-2.1, False)]:
        delta = np.zeros(21)
        delta[7] = step
        ok, rep = transition_success(pair(delta), np.array([0.1, 0.1]))
        assert rep.mean_ok[0] and rep.max_step[0] == abs(step)  # mean 2/21: only the max can fail
        assert ok.tolist() == [expected] and rep.max_ok.tolist() == [expected], step


def test_transition_counts_over_a_sequence():
    thetas = np.zeros((4, 21))
    thetas[2, 0] = 3.0  # 1 → 2 and 2 → 3 jump one joint by 3 rad
    ok, rep = transition_success(thetas, np.array([0.1, 0.1, 0.1, 0.1]))
    assert ok.tolist() == [True, False, False]
    assert (rep.count, rep.total, rep.rate) == (1, 3, pytest.approx(1 / 3))
    ok, rep = transition_success(thetas[:1], np.array([0.1]))
    assert len(ok) == 0 and math.isnan(rep.rate)
    with pytest.raises(ValueError):
        transition_success(thetas, np.array([0.1, 0.1]))


# --- the engine on the shipped self-model, tiny budgets ---------------------------------------------------------

needs_model = pytest.mark.skipif(not DEFAULT_MODEL.is_file(), reason=f"shipped self-model missing: {DEFAULT_MODEL}")


@pytest.fixture(scope="module")
def seq(hand):
    if not DEFAULT_MODEL.is_file():
        pytest.skip(f"shipped self-model missing: {DEFAULT_MODEL}")
    torch.set_num_threads(1)
    model, _ = load_selfmodel(DEFAULT_MODEL, hand, device="cpu")
    with SequenceImitator(model, TINY, loss_cfg=LossConfig(use_clip=False, crop_size=model.cfg.resolution)) as s:
        yield s


@pytest.fixture(scope="module")
def moving(seq, hand):
    """A synthetic sequence: the shadows of a free pose moving slowly (0.06 rad per frame in 8 joints), and the
    true poses ``(4, 21)``."""
    q0 = free_poses(hand, 1, seed=3)[0]
    direction = np.zeros(21)
    direction[[1, 2, 5, 6, 9, 10, 13, 14]] = 0.06
    steps = np.arange(4)[:, None]
    with CollisionWorld(hand) as world:
        if world.in_collision(np.clip(q0 + steps * direction, hand.lower, hand.upper)).any():
            direction = -direction
    poses = np.clip(q0 + steps * direction, hand.lower, hand.upper)
    masks = seq.renderer.render(poses)
    return masks, expressive_masks(masks), poses


def test_presets():
    assert (PAPER_SEQUENCE.first.batch, PAPER_SEQUENCE.first.iterations) == (500, 3000)
    assert (PAPER_SEQUENCE.next.batch, PAPER_SEQUENCE.next.iterations, PAPER_SEQUENCE.next.init_noise) == (
        128,
        1200,
        0.05,
    )
    assert PAPER_SEQUENCE.refine == RefineConfig()
    assert CPU_SEQUENCE.first.batch * CPU_SEQUENCE.first.iterations < PAPER_SEQUENCE.first.batch * 3000
    with pytest.raises(ValueError):
        SequenceConfig(mode="parallel")
    with pytest.raises(ValueError):
        SequenceConfig(candidates=0)


@pytest.mark.slow
@needs_model
def test_inherited_initialisation_keeps_consecutive_poses_close(seq, moving, hand):
    masks, expressive, _ = moving
    runs = {}
    for mode in ("independent", "sequential"):
        r = seq.imitate(masks, expressive, cfg=replace(TINY, mode=mode, temporal=mode == "sequential"))
        assert not r.cancelled and len(r.keyframes) == 4
        thetas = r.thetas
        assert np.all(thetas >= hand.lower - 1e-9) and np.all(thetas <= hand.upper + 1e-9)
        assert all(k.collision_free for k in r.keyframes)
        with CollisionWorld(hand) as world:  # the flag is the collision world's verdict
            assert not world.in_collision(thetas).any()
        assert np.array_equal(r.shadows, seq.renderer.render(thetas))
        runs[mode] = np.abs(np.diff(thetas, axis=0)).mean(axis=1)  # (3,) mean|Δθ| per transition
    # sequential steps are a fraction of independent ones, and small next to the transition bound
    assert runs["sequential"].mean() < 0.3 * runs["independent"].mean(), runs
    assert runs["sequential"].max() < 0.5 * TransitionConfig().max_mean_step, runs


@pytest.mark.slow
@needs_model
def test_loss_components_and_evaluation(seq, moving):
    masks, expressive, _ = moving
    r = seq.imitate(masks[:2], expressive[:2], cfg=replace(TINY, mode="independent", expressive=False, temporal=False))
    k0, k1 = r.keyframes
    w = seq.loss_cfg.w_temporal
    # what the row optimised: no expressive, no temporal term (NaN = not computed) ...
    assert math.isnan(k1.loss["exp_iou"]) and math.isnan(k1.loss["temporal"]) and math.isnan(k1.loss["clip"])
    assert k1.loss["total"] == pytest.approx(k1.loss["base"])
    # ... and the common measure: the expressive term where masks exist, the temporal term from the 2nd keyframe
    assert math.isnan(k0.evaluation["temporal"]) and math.isfinite(k0.evaluation["exp_iou"])
    assert k1.evaluation["temporal"] == pytest.approx(w * np.sum((k1.theta - k0.theta) ** 2), rel=1e-6)
    assert k1.evaluation["base"] == pytest.approx(k1.loss["base"], rel=1e-6)
    assert k1.total("image") == pytest.approx(k1.evaluation["base"] + k1.evaluation["expr"])
    assert k1.total("full") == pytest.approx(k1.evaluation["total"], rel=1e-6)
    rep = r.transitions()
    ok, _ = transition_success(r.thetas, r.totals("base"))
    assert rep.ok.tolist() == ok.tolist() and rep.total == 1
    # the sequential +Exp+Temp row computes both terms in what it optimised
    s = seq.imitate(masks[:2], expressive[:2], cfg=TINY)
    assert math.isfinite(s.keyframes[1].loss["exp_iou"])
    d2 = np.sum((s.keyframes[1].theta - s.keyframes[0].theta) ** 2)
    assert s.keyframes[1].loss["temporal"] == pytest.approx(w * d2, rel=1e-6)
    with pytest.raises(ValueError, match="expressive masks"):
        seq.imitate(masks, None, cfg=TINY)
    with pytest.raises(ValueError):
        seq.imitate(masks[0], None, cfg=replace(TINY, expressive=False))


@needs_model
def test_refinement_keeps_the_temporal_term(seq, hand):
    q = free_poses(hand, 1, seed=11)[0]
    loss_fn = ImageLoss(seq.renderer.render_one(q), seq.loss_cfg)
    rng = np.random.default_rng(4)
    start = np.clip(q + rng.normal(0, 0.15, 21), hand.lower, hand.upper)
    with CollisionWorld(hand) as world:
        while world.in_collision(start)[0]:
            start = np.clip(q + rng.normal(0, 0.15, 21), hand.lower, hand.upper)
    cfg = RefineConfig(restarts=4, steps=60)
    free = seq.refiner.refine(loss_fn, start, cfg)
    assert math.isnan(free.components["temporal"])
    assert free.loss == pytest.approx(free.components["base"], rel=1e-6)  # None: the shadow alone, as before
    kept = seq.refiner.refine(loss_fn, start, cfg, theta_prev=start)
    c, w = kept.components, seq.loss_cfg.w_temporal
    dist2 = float(np.sum((kept.theta - start) ** 2))
    assert dist2 > 0 and c["temporal"] == pytest.approx(w * dist2, rel=1e-6)  # the reported term is w·‖θ − θ_prev‖²
    assert c["total"] == pytest.approx(c["base"] + c["temporal"], rel=1e-6) and kept.loss == pytest.approx(c["total"])
    # it moved only as far as the better shadow paid for: w·‖θ − θ_prev‖² ≤ (start's loss − its own base loss)
    assert kept.collision_free and kept.start_loss == pytest.approx(free.start_loss)
    assert c["temporal"] <= kept.start_loss - c["base"] + 1e-9
    assert np.linalg.norm(kept.theta - start) < 0.8 * np.linalg.norm(free.theta - start)  # measured 0.39 vs 0.70


@pytest.mark.slow
@needs_model
def test_progress_and_cancel_return_the_keyframes_done(seq, moving):
    masks, expressive, _ = moving
    stages, cancel, when = [], threading.Event(), {}

    def progress(p: Progress):
        stages.append(p.stage)
        if p.stage.startswith("keyframe 2/4") and not cancel.is_set():
            when["set"] = time.perf_counter()
            cancel.set()

    slow = replace(TINY, next=SearchConfig(batch=8, iterations=5000, lr=0.08, log_every=1))
    r = seq.imitate(masks, expressive, progress, cancel, cfg=slow)
    assert time.perf_counter() - when["set"] < 1.0
    assert r.cancelled and r.requested == 4 and len(r.keyframes) == 1  # the interrupted keyframe is left out
    assert r.keyframes[0].index == 0 and r.keyframes[0].collision_free
    assert "keyframe 1/4: search" in stages and "keyframe 1/4: refine" in stages and "keyframe 2/4: search" in stages
    assert r.transitions().total == 0
    r = seq.imitate(masks, expressive, cancel=cancel, cfg=slow)  # already set: nothing done, promptly
    assert r.cancelled and r.keyframes == [] and r.thetas.shape == (0, 21)


@needs_model
def test_keyframe_targets_and_closing(seq, moving):
    masks, expressive, _ = moving
    m, e = keyframe_targets(masks, expressive, np.array([2, 0]))
    assert np.array_equal(m, masks[[2, 0]]) and np.array_equal(e, expressive[[2, 0]])
    inner = SequenceImitator(seq.model, TINY, imitator=seq.imitator)
    inner.close()  # a borrowed imitator stays open
    assert not seq.refiner.closed
    own = SequenceImitator(seq.model, TINY)
    own.close()
    with pytest.raises(ClosedError):
        own.imitate(masks, expressive)
