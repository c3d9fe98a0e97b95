"""Projects (studio.project.project): round trips, crash safety, undo/redo laws, missing sources, format versions,
painted strokes, export, colour footage (staleness: tests/test_project_stale.py; the ``project`` verbs:
tests/test_project_cli.py)."""

from __future__ import annotations

import json
import logging
import math
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image
from project_support import VIDEO, S, blob, make, rest_show  # the project tests' own helpers, beside this file

from studio.motion.show import load_show
from studio.project.project import Project, ProjectError
from studio.project.project_format import state_doc
from studio.project.status import SourceMissing
from studio.targets.video import SegmentationNeeded

CLI = [sys.executable, "-m", "studio.cli.main"]
ROOT = Path(__file__).resolve().parents[1]


def test_create_loads_frames_masks_and_keyframes(tmp_path, sources):
    p = make(tmp_path, sources)
    assert len(p.frames) == 9 and [f.source for f in p.frames] == [0] * 8 + [1]
    assert p.state.targets.shape == p.state.auto.shape == (9, S, S)
    assert p.state.auto[8].any()  # the ring's hole
    kf_sources = {p.frames[kf.representative].source for kf in p.keyframes}
    assert kf_sources == {0, 1} and 2 <= len(p.keyframes) <= 5
    assert sorted(m for kf in p.keyframes for m in kf.members) == list(range(9))
    assert p.sources[0].kind == "folder" and p.sources[1].kind == "still" and len(p.sources[0].sha256) == 64
    assert (tmp_path / "p.shadow" / "project.json").is_file()
    assert p.pending_keyframes() == [kf.id for kf in p.keyframes] and not p.can_undo
    with pytest.raises(ProjectError, match="already exists"):
        make(tmp_path, sources)
    with pytest.raises(ProjectError, match=r"ends in \.shadow"):
        Project.create(tmp_path / "plain", sources=[str(sources[1])])


def test_round_trip_keeps_every_field_and_masks_bit_exact(tmp_path, sources, hand, rng):
    p = make(tmp_path, sources)
    p.paint(2, additions=blob(rng), erasures=blob(rng))
    p.paint(8, erasures=blob(rng))
    new = p.add_keyframe(5) if len(p.keyframes[0].members) > 1 else p.keyframes[0].id
    p.set_keyframe_time(new, 1.25)
    p.set_hold(new, True)
    p.set_weights(w_iou=0.45, w_exp_iou=0.9)
    shadow = (rng.random((64, 64)) > 0.5).astype(np.uint8)
    theta = rng.uniform(hand.lower, hand.upper)
    p.set_result(new, theta, {"total": 0.25, "clip": math.nan}, shadow, evaluation={"base": 0.2}, seconds=1.5,
                 awaits="together")  # fmt: skip
    p.set_show(rest_show(hand))
    q = Project.open(p.path)
    assert state_doc(q.state) == state_doc(p.state)
    for name in ("targets", "auto"):
        assert np.array_equal(getattr(q.state, name), getattr(p.state, name))
        assert getattr(q.state, name).dtype == np.uint8
    for layer in ("additions", "erasures"):
        a, b = getattr(p.state, layer), getattr(q.state, layer)
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
    r = q.results[new]
    assert np.array_equal(r.shadow, shadow) and r.seconds == 1.5 and r.evaluation == {"base": 0.2}
    assert r.awaits == "together" and q.summary()["keyframes"][[k.id for k in q.keyframes].index(new)]["awaits"]
    assert np.array_equal(r.theta(hand.joint_names), theta)  # every angle bit for bit
    assert r.loss["total"] == 0.25 and math.isnan(r.loss["clip"])
    assert q.keyframes == p.keyframes and q.frames == p.frames and q.weights == p.weights
    assert q.state.keyframe(new).time_s == 1.25 and q.state.keyframe(new).hold
    assert q.show.equals(p.show) and not q.is_show_stale() and not q.is_stale(new)
    assert q.sources == p.sources and q.state.video == VIDEO and q.state.clustering == p.state.clustering
    folder = sorted(x.name for x in p.path.iterdir() if x.name != ".lock")  # the write lock stays
    assert folder[:3] == ["masks", "project.json", "results"] and folder[3].startswith("show-")


def test_a_save_killed_before_its_json_leaves_the_previous_project(tmp_path, sources):
    p = make(tmp_path, sources)
    before = state_doc(p.state)
    script = textwrap.dedent(f"""
        import os, numpy as np
        import studio.project.project_format as fmt
        from studio.project.project import Project
        p = Project.open({str(p.path)!r})
        fmt.write_json = lambda *a, **k: os._exit(3)   # killed after the new masks, before project.json
        m = np.zeros(({S}, {S}), np.uint8); m[3:9, 3:9] = 1
        p.paint(1, additions=m)
        os._exit(0)
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert r.returncode == 3, r.stderr
    masks = list((p.path / "masks").iterdir())
    assert any(m.name.startswith("add-") for m in masks)  # the new mask was written …
    q = Project.open(p.path)
    assert state_doc(q.state) == before and not q.state.additions  # … but the project is the previous one
    q.set_hold(q.keyframes[0].id, True)  # the next save removes what the killed one left
    assert not any(m.name.startswith("add-") for m in (p.path / "masks").iterdir())


@pytest.mark.slow
def test_sigkill_during_a_loop_of_saves_leaves_a_readable_project(tmp_path, sources):
    p = make(tmp_path, sources)
    script = textwrap.dedent(f"""
        import sys, numpy as np
        from studio.project.project import Project
        p = Project.open({str(p.path)!r})
        rng = np.random.default_rng(int(sys.argv[1]))
        for i in range(100000):
            m = (rng.random(({S}, {S})) > 0.7).astype(np.uint8)
            p.paint(int(rng.integers(len(p.frames))), additions=m, erasures=m.T.copy())
            p.set_weights(w_iou=float(rng.random()))
            print("saved", i, flush=True)
    """)
    seen = set()
    for seed, delay in ((1, 0.37), (2, 0.71), (3, 1.13)):
        proc = subprocess.Popen([sys.executable, "-c", script, str(seed)], stdout=subprocess.PIPE, text=True)
        assert proc.stdout.readline().startswith("saved")  # it is saving
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        q = Project.open(p.path)  # every file it names is there and matches its hash
        seen.add(json.dumps(state_doc(q.state), sort_keys=True))
        assert q.state.additions and len(q.frames) == 9
    assert len(seen) == 3  # each kill left a different (later) saved state


# ---------------------------------------------------------------- undo / redo laws

EDITS = st.lists(
    st.tuples(
        st.sampled_from(
            ["paint", "clear", "hold", "time", "move", "add", "remove", "weights", "tau", "result", "hz", "threshold"]
        ),
        st.integers(0, 10_000),
    ),
    min_size=1,
    max_size=8,
)


@pytest.fixture(scope="module")
def base_project(tmp_path_factory, write_sources):
    return make(tmp_path_factory.mktemp("undo"), write_sources(tmp_path_factory.mktemp("undo_src"))).path


def apply(p: Project, op: str, x: int) -> None:
    rng = np.random.default_rng(x)
    kfs = p.keyframes
    k = kfs[x % len(kfs)].id
    frame = x % len(p.frames)
    if op == "paint":
        p.paint(frame, additions=blob(rng) if x % 3 else None, erasures=blob(rng) if x % 2 else None)
    elif op == "clear":
        p.clear_paint(frame, erasures=bool(x % 2))
    elif op == "hold":
        p.set_hold(k, bool(x % 2))
    elif op == "time":
        p.set_keyframe_time(k, None if x % 5 == 0 else x / 100)
    elif op == "move":
        p.move_frame(frame, k)
    elif op == "add":
        p.add_keyframe(frame)
    elif op == "remove":
        p.remove_keyframe(k)
    elif op == "weights":
        p.set_weights(w_iou=x / 10_000)
    elif op == "tau":
        p.recluster(0.2 + 0.6 * x / 10_000)
    elif op == "hz":
        p.set_sampling(hz=[2.0, 4.0, 8.0][x % 3])
    elif op == "threshold":
        p.set_threshold(video=None if x % 2 else 100.0, still=[25.0, 60.0, None][x % 3])
    else:
        p.set_result(k, rng.uniform(-0.1, 0.1, 21), {"total": x / 10_000}, blob(rng, (16, 16)))


@pytest.mark.slow
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=EDITS)
def test_undo_and_redo_laws(base_project, edits):
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "p.shadow"
        shutil.copytree(base_project, path)
        p = Project.open(path)
        start = state_doc(p.state)
        changed = 0
        for op, x in edits:
            before = state_doc(p.state)
            try:
                apply(p, op, x)
            except ProjectError:  # an edit that cannot be made records nothing and changes nothing
                assert state_doc(p.state) == before
                continue
            changed += state_doc(p.state) != before
        end = state_doc(p.state)
        assert len(p.history) == changed and not p.can_redo
        if changed:  # undo then redo returns the end state
            p.undo()
            p.redo()
            assert state_doc(p.state) == end and state_doc(Project.open(path).state) == end
        for _ in range(changed):  # as many undos return the start, on disk too
            assert p.undo() is not None
        assert state_doc(p.state) == start and not p.can_undo and p.undo() is None
        assert state_doc(Project.open(path).state) == start
        while p.can_redo:
            p.redo()
        assert state_doc(p.state) == end


def test_keyframe_edits_keep_every_frame_in_one_keyframe_of_its_source(tmp_path, sources):
    p = make(tmp_path, sources)
    video_kfs = [kf for kf in p.keyframes if p.frames[kf.representative].source == 0]
    still_kf = next(kf for kf in p.keyframes if p.frames[kf.representative].source == 1)
    with pytest.raises(ProjectError, match="only keyframe of source 1"):
        p.remove_keyframe(still_kf.id)
    with pytest.raises(ProjectError, match="another source"):
        p.move_frame(0, still_kf.id)
    k = p.add_keyframe(max(video_kfs[0].members))
    assert p.state.keyframe(k).members == (max(video_kfs[0].members),) and p.state.keyframe(k).edited
    p.remove_keyframe(k)
    assert k not in {kf.id for kf in p.keyframes}
    for kf in p.keyframes:
        assert kf.representative in kf.members and len({p.frames[m].source for m in kf.members}) == 1
    assert sorted(m for kf in p.keyframes for m in kf.members) == list(range(9))
    assert (p.assignment() >= 0).all()


# ---------------------------------------------------------------- sources, versions, staleness


def test_a_missing_source_is_reported_with_its_old_path(tmp_path, sources, caplog):
    p = make(tmp_path, sources)
    k = p.keyframes[0].id
    target, _ = p.keyframe_masks(k)
    p.set_result(k, np.zeros(21), {"total": 0.1}, target)
    old = p.sources[0]
    moved = shutil.move(str(sources[0]), str(tmp_path / "elsewhere"))
    with caplog.at_level(logging.WARNING):
        q = Project.open(p.path)
    assert [(m.index, m.path, m.absolute) for m in q.missing_sources] == [(0, old.path, old.absolute)]
    assert old.absolute in caplog.text and "missing" in caplog.text
    assert q.summary()["sources"][0]["missing"] and len(q.frames) == 9 and not q.is_stale(k)
    with pytest.raises(SourceMissing, match="relink source 0"):
        q.set_sampling(hz=4.0)
    q.relink_source(0, moved)  # same content: everything kept
    assert not q.missing_sources and q.sources[0].absolute == str(Path(moved).resolve()) and not q.is_stale(k)
    q.set_sampling(hz=4.0)
    assert len(q.frames) == 5 and q.state.video.hz == 4.0


def test_a_newer_format_version_is_refused_naming_it(tmp_path, sources):
    p = make(tmp_path, sources)
    doc = json.loads((p.path / "project.json").read_text())
    (p.path / "project.json").write_text(json.dumps(doc | {"version": 7}))
    with pytest.raises(ProjectError, match=r"version 7, newer than version 1.*update"):
        Project.open(p.path)
    (p.path / "project.json").write_text(json.dumps(doc | {"format": "something-else"}))
    with pytest.raises(ProjectError, match="not a Shadow Studio project"):
        Project.open(p.path)


def test_painted_strokes_survive_a_re_run(tmp_path, sources, rng):
    p = make(tmp_path, sources)
    stroke = blob(rng)
    p.paint(8, additions=stroke)  # the still
    p.paint(0, erasures=stroke)
    p.set_threshold(video=100.0, still=30.0)
    p.set_sampling(hz=4.0)
    assert np.array_equal(p.state.additions["1:0"], stroke) and np.array_equal(p.state.erasures["0:0"], stroke)
    combined = p.combined_masks()
    still = next(i for i, f in enumerate(p.frames) if f.source == 1)
    assert (combined[still][stroke == 1] == 1).all() and (combined[0][stroke == 1] == 0).all()
    assert not (p.state.auto[still][stroke == 1] == 1).all()  # the automatic mask is kept apart


def test_export_writes_the_current_show(tmp_path, sources, hand):
    p = make(tmp_path, sources)
    with pytest.raises(ProjectError, match="no planned show"):
        p.export_show(tmp_path / "show.json")
    p.set_show(rest_show(hand, 2.0))
    out = p.export_show(tmp_path / "show.json")
    assert load_show(out).equals(p.show)
    p.set_hold(p.keyframes[0].id, True)
    assert p.is_show_stale()


def test_colour_footage_needs_and_uses_a_first_frame_box(tmp_path):
    folder = tmp_path / "colour"
    folder.mkdir()
    rng = np.random.default_rng(3)
    ground = (rng.integers(0, 40, (64, 80, 3)) + np.array([40, 140, 60])).astype(np.uint8)  # green, textured
    for i in range(4):
        frame = ground.copy()
        frame[20:44, 10 + 6 * i : 34 + 6 * i] = (220, 40, 40)  # a red square moving right
        Image.fromarray(frame).save(folder / f"{i:05d}.png")
    with pytest.raises(SegmentationNeeded, match="colour footage.*box"):
        Project.create(tmp_path / "c.shadow", sources=[str(folder)], video=VIDEO)
    assert not (tmp_path / "c.shadow").exists()  # nothing made for a project that could not be
    p = Project.create(tmp_path / "c.shadow", sources=[str(folder)], video=VIDEO, box=(8, 18, 28, 28))
    assert p.sources[0].footage == "segmented" and p.sources[0].box == (8, 18, 28, 28) and len(p.frames) == 4
    assert p.state.targets.any(axis=(1, 2)).all()
    with pytest.raises(SegmentationNeeded, match="colour footage"):
        p.set_segmentation(0)  # no box, no mask: it cannot be read any more, and nothing changes
    assert p.sources[0].box == (8, 18, 28, 28) and not p.can_undo
    first = np.zeros((64, 80), np.uint8)
    first[20:44, 10:34] = 1
    p.set_segmentation(0, first_mask=first)
    q = Project.open(p.path)
    assert q.sources[0].box is None and np.array_equal(q.sources[0].first_mask, first)
    assert state_doc(q.state) == state_doc(p.state)
