"""What one mount for the whole show costs: roll auto names the keyframes that another roll would cast clearly
better (``RollChoice.apart``), the project keeps them with the roll, and the artist reads where each would read better
(the Optimise panel's mount line, ``project info``, a run's summary)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from studio.imitate.config import LossConfig
from studio.imitate.losses import ImageLoss
from studio.imitate.refine import Refiner
from studio.imitate.retrieval import RetrievalConfig, RetrievalIndex
from studio.imitate.roll_search import check_roll, choose_roll
from studio.project.demo import demo_sources
from studio.project.project import Project
from studio.project.project_read import Damaged
from studio.project.state import MountApart
from studio.project.summary import apart_text
from studio.sim.roll import wrap_deg
from studio.sim.shadow import Rig, ShadowRenderer
from widgets.mount import mount_line

R = 128


def elongated(shadows: np.ndarray, n: int) -> list[int]:
    """The ``n`` shadows of ``(P, R, R)`` the most taller than wide, tallest first."""
    ratio = []
    for s in shadows:
        rows, cols = np.nonzero(s.any(axis=1))[0], np.nonzero(s.any(axis=0))[0]
        ratio.append((rows[-1] - rows[0] + 1) / (cols[-1] - cols[0] + 1) if len(rows) else 0.0)
    return [int(i) for i in np.argsort(ratio)[::-1][:n]]


@pytest.mark.slow  # builds a 3,000-pose index (1.4 s)
def test_roll_auto_names_the_keyframe_its_one_mount_casts_worse(hand):
    """Two tall reachable shadows cast by a mount rolled 90° and one cast upright: the show's roll is 90° (two of
    three), and the upright one is named, with its own roll (upright, to the coarse step) where its first answer
    casts it better than on the show's mount; without it, or for one target, nothing is named."""
    renderer = ShadowRenderer(hand, Rig(resolution=R))
    index = RetrievalIndex.build(renderer, RetrievalConfig(size=3000, chunk=3000, shortlist=64))
    refiner = Refiner(renderer)
    make = lambda t, e: ImageLoss(t, LossConfig(use_clip=False, crop_size=R), None, e)  # noqa: E731
    try:
        theta = index.theta.astype(np.float64)
        a, b, c = elongated(renderer.render(theta[:200]), 3)
        side = ShadowRenderer(hand, Rig(resolution=R, roll=math.radians(90)))
        targets = np.stack([side.render_one(theta[a]), side.render_one(theta[b]), renderer.render_one(theta[c])])
        show = choose_roll(index, refiner, targets, make)
        assert abs(wrap_deg(show.deg - 90)) <= 2.0
        (named,) = show.apart
        assert named.target == 2 and abs(math.degrees(named.own_roll)) <= 7.5
        assert named.loss >= 1.5 * named.own_loss and named.loss - named.own_loss >= 0.05, named
        assert choose_roll(index, refiner, targets[:2], make).apart == []  # every keyframe wants the show's roll
        assert choose_roll(index, refiner, targets[2:], make).apart == []  # a still has the roll best for it
        # a roll the artist sets is measured the same way: at 90° the upright one is named, upright the tall ones
        (typed,) = check_roll(index, refiner, targets, make, 90.0)
        assert typed.target == 2 and typed.loss == pytest.approx(named.loss, abs=1e-6)
        assert {a.target for a in check_roll(index, refiner, targets, make, 0.0)} == {0, 1}
        assert check_roll(index, refiner, targets[2:], make, 90.0) == []  # a still: nothing to weigh it against
    finally:
        refiner.close()


@pytest.fixture
def demo(tmp_path):
    """The bundled demo's sources (the ASL "o", then the horse) as a fresh project."""
    return Project.create(tmp_path / "demo.shadow", sources=demo_sources())


def test_the_project_keeps_the_keyframes_its_mount_costs_and_says_where_they_read_better(demo, capsys):
    from studio.cli.main import main

    kf = demo.keyframes[0]
    demo.set_chosen_roll(math.radians(-83.4), loss=0.18, upright_loss=0.219,
                         apart=[MountApart(kf.id, kf.representative, 0.2345, math.radians(-15.0), 0.1062)])  # fmt: skip
    again = Project.open(demo.path)  # written and read back
    assert again.mount.apart == demo.mount.apart and len(again.mount.apart) == 1
    (entry,) = again.summary()["mount"]["apart"]
    assert entry == {"keyframe": kf.id, "source": "asl_o.jpeg", "loss": 0.2345, "own_roll_deg": -15.0,
                     "own_loss": 0.1062}  # fmt: skip
    said = (f"one mount serves the whole show: keyframe {kf.id} (asl_o.jpeg) would cast better at roll -15° "
            "(first-answer outline loss 0.106 there, 0.234 on this mount); set another roll by hand, or give it a "
            "show of its own")  # fmt: skip
    assert apart_text([entry]) == said
    assert said in mount_line(again)  # the Optimise panel's line under the roll box
    assert main(["project", "info", str(demo.path)]) == 0
    out = capsys.readouterr().out
    assert f"  {said}\n" in out and json.loads(out.strip().splitlines()[-1])["mount"]["apart"] == [entry]
    two = [entry, dict(entry, keyframe=3, source="muybridge_horse.gif", own_roll_deg=30.0)]
    tail = (f"{kf.id} (asl_o.jpeg) at -15° (0.106, 0.234); 3 (muybridge_horse.gif) at +30° (0.106, 0.234); set "
            "another roll by hand, or give them a show of their own")  # fmt: skip
    assert apart_text(two).endswith(tail)
    demo.set_roll(-83.4)  # the artist's own roll: nothing named until it is measured
    assert demo.mount.apart == () and demo.summary()["mount"]["apart"] == [] and "one mount" not in mount_line(demo)
    demo.set_roll_costs(math.radians(-83.4), again.mount.apart)  # measured (roll_check_job): named as for auto's
    assert said in mount_line(Project.open(demo.path)) and demo.summary()["mount"]["apart"] == [entry]
    demo.set_roll_costs(math.radians(10.0), ())  # measured for a roll no longer set: kept as it is
    assert demo.summary()["mount"]["apart"] == [entry]


def test_a_keyframe_made_again_since_the_roll_was_chosen_is_not_named(demo):
    kf = demo.keyframes[-1]
    demo.set_chosen_roll(0.5, apart=[MountApart(kf.id, kf.representative + 1, 0.3, 0.0, 0.1)])  # another frame
    assert demo.summary()["mount"]["apart"] == [] and "one mount" not in mount_line(demo)
    demo.set_chosen_roll(0.5, apart=[MountApart(kf.id + 100, kf.representative, 0.3, 0.0, 0.1)])  # no such keyframe
    assert demo.summary()["mount"]["apart"] == []


@pytest.mark.parametrize("entry", [{"keyframe": -1, "frame": 0, "loss": 0.2, "own_roll_deg": 0, "own_loss": 0.1},
                                   {"keyframe": 0, "frame": 0, "loss": "x", "own_roll_deg": 0, "own_loss": 0.1},
                                   {"keyframe": 0, "frame": 0, "loss": 0.2, "own_loss": 0.1}, "0"])  # fmt: skip
def test_a_damaged_apart_entry_is_refused_in_one_line(demo, entry):
    doc = demo.path / "project.json"
    data = json.loads(doc.read_text())
    data["mount"]["apart"] = [entry]
    doc.write_text(json.dumps(data))
    with pytest.raises(Damaged, match="the mount entry is not understood"):
        Project.open(demo.path)


@pytest.mark.slow  # the shipped model and index (26 s on a machine whose index cache is empty)
def test_the_roll_job_of_the_demo_names_the_still_its_sideways_mount_casts_worse(demo):
    """The demo's first run chooses one roll for the still and the horse: the horse's sideways mount (its four
    keyframes), and the ASL "o" named, with the upright-ish roll where it would read better."""
    from studio.jobs.job import JobState
    from studio.jobs.queue import JobQueue
    from studio.project.jobs import roll_job

    queue = JobQueue("thread")
    try:
        job = queue.submit(roll_job(demo))
        assert job.wait(300) == JobState.DONE, job.error
    finally:
        queue.close()
    assert demo.mount.auto and demo.mount.chosen and abs(wrap_deg(math.degrees(demo.mount.roll))) > 45
    (named,) = demo.mount.apart
    assert named.keyframe == demo.keyframes[0].id and demo.frames[named.frame].source == 0  # the still
    assert abs(wrap_deg(math.degrees(named.own_roll))) < 45 and named.own_loss < named.loss
    assert "keyframe 0 (asl_o.jpeg) would cast better at roll" in mount_line(Project.open(demo.path))


@pytest.mark.slow  # the shipped model and index, the start of a keyframe's optimisation
def test_a_run_measures_what_the_roll_the_artist_set_costs_before_it_poses_the_keyframes(demo):
    """The artist sets the horse's sideways roll by hand: the run first measures what it costs the show (the ASL "o"
    named, as roll auto names it), then poses the keyframes (cancelled here once the first keyframe's job starts)."""
    import threading

    from studio.project.run import run_project

    demo.set_roll(-83.4)
    cancel, jobs = threading.Event(), []

    def on_job(job, what) -> None:
        jobs.append((job.kind, what))
        if job.kind != "check-roll":
            cancel.set()  # the keyframes' poses are not what this test is about

    report = run_project(demo, cancel=cancel, on_job=on_job)
    assert report.cancelled and jobs[0] == (
        "check-roll",
        f"what the mount roll -83.4° costs {len(demo.keyframes)} keyframes",
    )
    assert not demo.mount.auto and math.degrees(demo.mount.roll) == pytest.approx(-83.4)  # the artist's roll stays
    (named,) = demo.mount.apart
    assert named.keyframe == demo.keyframes[0].id and abs(wrap_deg(math.degrees(named.own_roll))) < 45
    assert "set another roll by hand" in mount_line(Project.open(demo.path))


@pytest.mark.slow  # the shipped model and index
def test_the_optimise_panels_roll_set_by_hand_is_measured_as_it_is_set(demo):
    """The artist types the horse's roll in the Optimise tab and presses Set: within the job that measures it (in the
    background) the mount line names the ASL "o" and where it would read better; roll 0 (the paper's rig) and a still
    measure nothing."""
    from studio.jobs.job import JobState
    from studio.project.jobs import queue_for
    from widgets.mount import MountControl
    from widgets.state import StudioState

    state = StudioState(demo, queue_for(demo))
    said: list[str] = []
    try:
        control = MountControl(state, lambda text, error=False: said.append(text))
        control.box.value = "-83.4"
        assert control.apply() and "mount roll set to -83.4" in said[-1]
        (job,) = [j for j in state.queue.jobs() if j.kind == "check-roll"]
        assert job.wait(300) == JobState.DONE, job.error
        assert "keyframe 0 (asl_o.jpeg) would cast better at roll" in control.line.value  # redrawn as it landed
        assert "set another roll by hand" in control.line.value
        control.box.value = "0"
        assert control.apply() and control.measure() is None and "would cast better" not in control.line.value
    finally:
        state.close()
