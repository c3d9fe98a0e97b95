"""studio.imitate.live_best: what a still or a keyframe shows while it runs only ever gets better, is collision-free,
and carries the rendered loss of the pose on show; the kept pose is never worse than a pose shown."""

from __future__ import annotations

import math

import numpy as np
import pytest

from studio.errors import Progress
from studio.imitate.config import ImitateConfig, LossConfig, RefineConfig, SearchConfig, SequenceConfig, SweepConfig
from studio.imitate.live_best import LiveBest
from studio.imitate.losses import ImageLoss
from studio.imitate.retrieval import RetrievalConfig, RetrievalIndex
from studio.imitate.sequence import SequenceImitator
from studio.imitate.still import Imitator
from studio.learn.selfmodel import SelfModel, SelfModelConfig
from studio.sim.shadow import Rig, ShadowRenderer

LOSS = LossConfig(use_clip=False, crop_size=32)
SWEEP = SweepConfig(starts=2, draws=48, wrist_draws=16, passes=1)


@pytest.fixture(scope="module")
def imitator(hand):
    renderer = ShadowRenderer(hand, Rig(resolution=32))
    index = RetrievalIndex.build(renderer, RetrievalConfig(size=1200, chunk=600, shortlist=48, seed=5))
    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    search = SearchConfig(batch=8, iterations=30, log_every=3)  # an untrained model: its search wanders
    refine = RefineConfig(method="cmaes", restarts=2, steps=12, popsize=8, log_every=2)
    with Imitator(model, loss_cfg=LOSS, retrieval=index, search=search, refine=refine, sweep=SWEEP,
                  config=ImitateConfig(candidates=2)) as im:  # fmt: skip
        yield im


class Recorder:
    """The caller's side: every report and every pose given, in order."""

    def __init__(self):
        self.events: list[tuple] = []

    def progress(self, p: Progress):
        self.events.append(("report", p.stage, p.best))

    def best_pose(self, theta):
        self.events.append(("pose", np.array(theta)))


def _check_stream(rec: Recorder, imitator: Imitator, loss_fn: ImageLoss, theta_prev=None) -> list[float]:
    """Reported numbers never rise; each pose given is collision-free and the next report carries its rendered
    loss. Returns the rendered losses of the poses given."""
    shown, reported, last = [], [], None
    for e in rec.events:
        if e[0] == "pose":
            assert not imitator.refiner.world.in_collision(e[1])[0]
            last = float(imitator.refiner.score(loss_fn, e[1][None], theta_prev)[0][0])
            shown.append(last)
        elif not math.isnan(e[2]):
            reported.append(e[2])
            assert last is not None and e[2] == pytest.approx(last, abs=1e-9), e  # the loss of the pose on show
    assert reported and all(b <= a for a, b in zip(reported, reported[1:])), reported
    assert all(b < a for a, b in zip(shown, shown[1:])), shown  # each pose given beats the one before
    return shown


def test_a_still_shows_only_better_collision_free_poses_and_keeps_one_no_worse(imitator, free_poses):
    target = imitator.renderer.render_one(free_poses(1, seed=4)[0])
    rec = Recorder()
    result = imitator.imitate(target, progress=rec.progress, best_pose=rec.best_pose)
    shown = _check_stream(rec, imitator, imitator.loss_fn(target))
    stages = {e[1] for e in rec.events if e[0] == "report"}
    assert {"retrieve", "sweep", "search", "refine"} <= stages
    assert result.collision_free and result.loss["total"] <= shown[-1] + 1e-9  # the kept pose: no worse than shown
    assert result.unrefined_loss["total"] <= shown[0] + 1e-9  # never worse than the first answer either


def test_a_sequence_keyframe_streams_the_same_way_with_the_temporal_term(imitator, free_poses):
    masks = np.stack([imitator.renderer.render_one(t) for t in free_poses(2, seed=9)])
    cfg = SequenceConfig(
        first=SearchConfig(batch=8, iterations=12, log_every=3),
        next=SearchConfig(batch=4, iterations=9, log_every=3),
        refine=RefineConfig(method="cmaes", restarts=1, steps=8, popsize=8, log_every=2),
        candidates=1, expressive=False, retrieve=True, sweep=SWEEP,
    )  # fmt: skip
    rec = Recorder()
    with SequenceImitator(cfg=cfg, imitator=imitator) as seq:
        result = seq.imitate(masks, progress=rec.progress, best_pose=rec.best_pose)
    assert len(result.keyframes) == 2
    for k, name in enumerate(("keyframe 1/2", "keyframe 2/2")):
        one = Recorder()
        one.events = _split(rec.events, name)
        prev = None if k == 0 else result.keyframes[0].theta  # keyframe 2 is scored with the temporal term
        shown = _check_stream(one, imitator, ImageLoss(masks[k], imitator.loss_cfg), prev)
        if k == 0:  # seeded from scratch: its pool holds every pose shown, so the kept pose is no worse
            assert result.keyframes[0].loss["total"] <= shown[-1] + 1e-9


def _split(events: list[tuple], name: str) -> list[tuple]:
    """The events of one keyframe: its reports, each with the pose given just before it (LiveBest gives a pose
    only right before a report of the same stage)."""
    out, pending = [], []
    for e in events:
        if e[0] == "pose":
            pending.append(e)
            continue
        if e[1].startswith(name + ":"):
            out += pending + [e]
        pending = []
    return out


def test_live_best_judges_each_pose_at_the_report_that_follows(imitator, hand, free_poses):
    poses = free_poses(3, seed=11)
    target = imitator.renderer.render_one(poses[0])
    loss_fn = imitator.loss_fn(target)
    exact = float(imitator.refiner.score(loss_fn, poses[:1])[0][0])
    rec = Recorder()
    live = LiveBest(imitator.refiner, loss_fn, rec.progress, rec.best_pose)
    live.report(Progress("index", 1, 2))  # no pose yet: NaN, nothing shown
    live.pose(poses[1])
    live.report(Progress("refine", 1, 9, 0.5))  # a stage with its own rendered loss: taken at it
    live.pose(poses[2])
    live.report(Progress("refine", 2, 9, 0.7))  # worse: not shown, the number stays
    live.pose(poses[0])
    live.report(Progress("keyframe 1/1: search", 3, 9, -5.0))  # a search's number is the model's: re-scored here
    reports = [e[2] for e in rec.events if e[0] == "report"]
    assert math.isnan(reports[0]) and reports[1:] == [0.5, 0.5, pytest.approx(exact)]
    assert sum(e[0] == "pose" for e in rec.events) == 2  # poses[1], then poses[0]; poses[2] was worse
    theta, loss = live.shown()
    assert theta.shape == (2, hand.dof) and np.allclose(theta[1], poses[0]) and loss[0] == 0.5


def test_a_colliding_pose_is_never_shown(imitator, hand):
    from studio.sim.sampling import sample_poses

    theta = sample_poses(hand, 400, np.random.default_rng(3))[0]
    hit = theta[imitator.refiner.world.in_collision(theta)][0]
    rec = Recorder()
    live = LiveBest(imitator.refiner, imitator.loss_fn(imitator.renderer.render_one(hit)), rec.progress, rec.best_pose)
    live.pose(hit)
    live.report(Progress("refine", 1, 1, 0.0))  # even at a claimed loss of 0
    assert len(rec.events) == 1 and rec.events[0][:2] == ("report", "refine") and math.isnan(rec.events[0][2])
    assert live.shown()[0].shape == (0, hand.dof) and live.theta is None
