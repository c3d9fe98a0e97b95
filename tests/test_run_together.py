"""A project run refines its keyframes together after posing them one after another (studio.project.run_together):
one job a stretch of consecutive keyframes of a source, poses within their reach of one another on the show's clock,
the run's objective never higher than one keyframe after another gave, results current, the show planned without a
late transition, and keyframes the run did not optimise never moved."""

from __future__ import annotations

import shutil
import threading
from dataclasses import replace

import numpy as np
import pytest

from studio.imitate.config import JointConfig, RefineConfig, SearchConfig, SequenceConfig
from studio.imitate.joint_refine import TOL
from studio.motion.limits import JointLimits
from studio.motion.reach import reach_pairs
from studio.project.project import Project
from studio.project.run import RunConfig, run_project
from studio.project.run_together import together_stretches
from studio.project.show_timing import transition_times
from studio.sim.hand import load_hand
from studio.targets.keyframes import KeyframeConfig
from studio.targets.video import DEFAULT_VIDEO

TINY = SequenceConfig(
    first=SearchConfig(batch=8, iterations=20), next=SearchConfig(batch=8, iterations=10, lr=0.08),
    refine=RefineConfig(steps=30, restarts=2), candidates=1,
)  # fmt: skip
TOGETHER = replace(TINY, joint=JointConfig(generations=25, popsize=12, both_orders=True))


def poses(project: Project) -> dict[int, np.ndarray]:
    names = load_hand().joint_names
    return {k: r.theta(names) for k, r in project.results.items()}


@pytest.fixture(scope="module")
def horse(tmp_path_factory):
    """The horse, a keyframe a frame (τ 0.9: five), upright, run one keyframe after another (the joint step off)."""
    folder = tmp_path_factory.mktemp("together")
    project = Project.create(folder / "horse.shadow", sources=[DEFAULT_VIDEO], clustering=KeyframeConfig(tau=0.9))
    project.set_roll(0.0)
    report = run_project(project, RunConfig(sequence=TINY), plan=False)
    assert report.error is None and not report.cancelled and len(project.keyframes) >= 2, report.message
    return project.path


def test_stretches_are_consecutive_keyframes_of_one_source(horse):
    project = Project.open(horse)
    ids = [kf.id for kf in project.keyframes]
    assert together_stretches(project, ids) == [ids]
    assert together_stretches(project, ids[:1]) == []
    assert together_stretches(project, [ids[0], *ids[2:]]) == ([ids[2:]] if len(ids) > 3 else [])


def test_a_run_refines_its_keyframes_together_within_their_reach(horse, tmp_path):
    path = tmp_path / "horse.shadow"
    shutil.copytree(horse, path)
    before = Project.open(horse)
    project = Project.open(path)
    ids = [kf.id for kf in project.keyframes]
    said = []
    report = run_project(project, RunConfig(sequence=TOGETHER), keyframes=ids,
                         on_job=lambda job, what: said.append(what))  # fmt: skip
    assert report.ok and report.show == "planned" and report.late == [], report.message
    assert said[-2].startswith(f"refining keyframes {ids[0]}–{ids[-1]} together")  # then the show
    assert project.pending_keyframes() == [] and not project.is_show_stale()  # every result current
    assert project.history[-2:] == [f"keyframes {ids[0]}–{ids[-1]} refined together", "planned show"]  # one undo
    got = poses(project)
    assert any(not np.array_equal(got[k], poses(before)[k]) for k in ids)  # it moved something
    limits = JointLimits.from_hand(load_hand(), RunConfig().plan.limits)
    for (a, b), d in reach_pairs(transition_times(project.state), limits, TOGETHER.clock_margin).items():
        assert (np.abs(got[a] - got[b]) - d).max() <= TOL, (a, b)
    total = sum(project.results[k].loss["total"] for k in ids)  # each with its temporal term: the joint objective
    assert total <= sum(before.results[k].loss["total"] for k in ids) + 1e-9
    assert all(project.results[k].collision_free for k in ids)


def test_keyframes_the_run_did_not_optimise_never_move(horse, tmp_path):
    path = tmp_path / "horse.shadow"
    shutil.copytree(horse, path)
    project = Project.open(path)
    ids = [kf.id for kf in project.keyframes]
    held = poses(project)
    said = []
    report = run_project(project, RunConfig(sequence=TOGETHER), keyframes=[ids[1]], plan=False,
                         on_job=lambda job, what: said.append(what))  # fmt: skip
    assert report.error is None and report.optimised == [ids[1]], report.message
    assert not any(w.startswith("refining") for w in said)  # a stretch of one: nothing to refine together
    assert not project.results[ids[1]].awaits  # nor anything left to refine at the next run
    got = poses(project)
    assert all(np.array_equal(got[k], held[k]) for k in ids if k != ids[1])


def test_a_run_cancelled_while_refining_together_refines_them_when_resumed(horse, tmp_path):
    """Cancelled while refining together: every keyframe posed one after another is saved, current, and awaits its
    refinement together (``project info`` says so). The next run, naming no keyframe, refines them together and
    plans the show, with the poses of the run that was not cancelled: the same command resumes the same show. So
    does a run stopped while posing."""
    whole = tmp_path / "whole.shadow"
    shutil.copytree(horse, whole)
    reference = Project.open(whole)
    ids = [kf.id for kf in reference.keyframes]
    assert run_project(reference, RunConfig(sequence=TOGETHER), keyframes=ids).ok
    assert not any(r.awaits for r in reference.results.values())

    path = tmp_path / "horse.shadow"
    shutil.copytree(horse, path)
    project = Project.open(path)
    cancel = threading.Event()

    def on_job(job, what):
        if what.startswith("refining"):
            cancel.set()

    report = run_project(project, RunConfig(sequence=TOGETHER), keyframes=ids, cancel=cancel, on_job=on_job)
    assert report.cancelled and report.show is None and "together cancelled" in report.message
    assert "the next run refines them together" in report.message
    reopened = Project.open(path)
    assert reopened.pending_keyframes() == []  # every keyframe posed one after another is saved, current
    assert all(r.awaits == "together" for r in reopened.results.values())
    assert all(kf["awaits"] == "together" for kf in reopened.summary()["keyframes"])
    said = []
    resumed = run_project(reopened, RunConfig(sequence=TOGETHER), on_job=lambda job, what: said.append(what))
    assert resumed.ok and resumed.optimised == [] and resumed.show == "planned", resumed.message
    assert resumed.refined == ids and f"refined {len(ids)} keyframes together that a stopped run" in resumed.message
    assert said[0].startswith(f"refining keyframes {ids[0]}–{ids[-1]} together")
    assert not any(r.awaits for r in reopened.results.values())
    got, want = poses(reopened), poses(reference)
    assert all(np.array_equal(got[k], want[k]) for k in ids)
    assert reopened.show.equals(replace(reference.show, created=reopened.show.created))  # the same show
    # stopped while posing the third keyframe of a new project: the two saved before it await the refinement, and
    # the resumed run poses the rest and refines all of them together, to the same poses
    fresh = Project.create(tmp_path / "fresh.shadow", sources=[DEFAULT_VIDEO], clustering=KeyframeConfig(tau=0.9))
    fresh.set_roll(0.0)
    assert [kf.id for kf in fresh.keyframes] == ids and len(ids) >= 3
    cancel, posed = threading.Event(), []

    def third(job, what):
        posed.append(what)
        if len(posed) == 3:
            cancel.set()

    assert run_project(fresh, RunConfig(sequence=TOGETHER), cancel=cancel, on_job=third).cancelled
    assert [fresh.results[k].awaits for k in ids[:2]] == ["together"] * 2 and fresh.pending_keyframes() == ids[2:]
    resumed = run_project(fresh, RunConfig(sequence=TOGETHER))
    assert resumed.ok and resumed.optimised == ids[2:] and resumed.refined == ids, resumed.message
    got = poses(fresh)
    assert all(np.array_equal(got[k], want[k]) for k in ids)
