"""The Keyframes panel driven from Python: τ's live count leaves the project alone until applied, the strip, and
every keyframe edit (add, remove, move a frame, time, hold) through the project, with undo and redo."""

from __future__ import annotations

import io
import re
import shutil

import numpy as np
import pytest
from PIL import Image

from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.project.project_format import state_doc
from studio.targets.keyframes import KeyframeConfig, cluster_keyframes
from studio.targets.video import DEFAULT_VIDEO, VideoConfig
from widgets.keyframes import KeyframesPanel, keyframes_panel
from widgets.state import StudioState


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    path = tmp_path_factory.mktemp("kf") / "horse.shadow"
    # 9 frames: 4 keyframes at τ 0.3, 1 at τ ≤ 0.25, 9 at τ ≥ 0.39
    Project.create(path, [DEFAULT_VIDEO], video=VideoConfig(size=48, hz=8.0), clustering=KeyframeConfig(tau=0.42))
    return path


@pytest.fixture
def state(folder, tmp_path):
    copy = tmp_path / "h.shadow"
    shutil.copytree(folder, copy)
    project = Project.open(copy)
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


def test_tau_counts_live_and_edits_only_when_applied(state):
    assert "Keyframes" in keyframes_panel(state).widget.children[0].value
    panel = KeyframesPanel(state)
    p = state.project
    before, n_frames = state_doc(p.state), len(p.frames)
    assert panel.counter.settle()  # the merge orders are worked out in the panel's thread
    assert n_frames == 9 and panel.live_count == len(p.keyframes) == 3
    assert len(panel.strip.children) == len(p.keyframes)
    last = p.keyframes[-1]
    card = panel.strip.children[-1]
    t0, t1 = p.frames[last.members[0]].time_s, p.frames[last.members[-1]].time_s
    assert bytes(card.children[0].value).startswith(b"\x89PNG")  # the representative's picture
    assert f"{len(last.members)} frames" in card.children[2].value and f"{t0:.2f}" in card.children[2].value
    assert len(last.members) == 1 or f"{t1:.2f}" in card.children[2].value
    card.children[1].click()  # select that cluster
    assert state.selection.keyframe == last.id and state.selection.frame == last.representative
    assert panel.keyframe.value == last.id
    panel.tau.value = 0.99
    high = panel.live_count
    panel.tau.value = 0.0
    assert panel.live_count == 2 < high == 9  # τ 0: the horse's shape changes, so two, never one; τ 0.99: each frame
    assert f"{panel.live_count} keyframes" in panel.count.value
    assert state_doc(p.state) == before and not p.can_undo  # the project is untouched
    state.edit("paint", 0, additions=np.ones(p.state.auto.shape[1:], np.uint8))  # the masks change: recounted
    panel.tau.value = 0.3
    assert panel.counter.settle()
    by_shape = cluster_keyframes(p.combined_masks(), KeyframeConfig(tau=0.3), p.state.targets)
    assert panel.live_count == len(by_shape.members)
    state.undo()
    before = state_doc(p.state)
    panel.tau.value = 0.99
    panel.apply_tau.click()
    assert len(p.keyframes) == high and p.state.clustering.tau == 0.99
    assert len(panel.strip.children) == high
    panel.undo.click()
    assert state_doc(p.state) == before and panel.undo.disabled and not panel.redo.disabled
    panel.redo.click()
    assert len(p.keyframes) == high


def test_add_remove_move_time_and_hold(state):
    panel = KeyframesPanel(state)
    p = state.project
    n = len(p.keyframes)
    frame = next(kf.members[-1] for kf in p.keyframes if len(kf.members) > 1)  # a frame that is not alone
    state.select(frame=frame)
    panel.add.click()
    assert panel.messages.text == "" and len(p.keyframes) == n + 1
    k = panel.selected()
    assert p.state.keyframe(k).members == (frame,) and len(panel.strip.children) == n + 1
    panel.hold.value = True
    assert p.state.keyframe(k).hold
    panel.clock.value = False
    panel.time.value = 2.5
    panel.set_time.click()
    assert p.state.keyframe(k).time_s == 2.5
    other = next(kf.id for kf in p.keyframes if kf.id != k)
    panel.move_to.value = other
    panel.move.click()  # the frame joins another keyframe: the lone keyframe disappears
    assert frame in p.state.keyframe(other).members and k not in [kf.id for kf in p.keyframes]
    for _ in range(3):
        panel.undo.click()
    assert p.state.keyframe(k).members == (frame,) and not p.state.keyframe(k).hold
    state.select(frame=frame, keyframe=k)
    panel.remove.click()
    assert len(p.keyframes) == n
    panel.undo.click()
    assert len(p.keyframes) == n + 1


def test_a_refused_edit_is_a_message(state):
    panel = KeyframesPanel(state)
    lone = next((kf for kf in state.project.keyframes if len(kf.members) == 1), None)
    if lone is None:
        state.select(frame=0)
        panel.add.click()
        lone = state.project.state.keyframe(panel.selected())
    state.select(frame=lone.representative)
    panel.add.click()  # already a keyframe of its own
    assert panel.messages.text and "Traceback" not in panel.messages.text


def test_the_slider_holds_the_default_tau_as_the_browser_will_snap_it(state):
    """The browser snaps a slider's value to its step and sends it back: with a step of 0.005 the default τ 0.404
    came back as 0.405, so the count shown and an "Apply τ" were at a τ the project never had."""
    panel = KeyframesPanel(state)
    try:
        tau, step = KeyframeConfig().tau, panel.tau.step
        assert abs(round((tau - panel.tau.min) / step) * step + panel.tau.min - tau) < 1e-9
    finally:
        panel.close()


def test_tau_follows_the_project_after_undo_redo_and_another_panels_edit(state):
    panel = KeyframesPanel(state)
    p = state.project
    assert panel.tau.value == p.state.clustering.tau == 0.42
    panel.tau.value = 0.99
    panel.apply_tau.click()
    assert p.state.clustering.tau == 0.99
    state.undo()
    assert p.state.clustering.tau == 0.42 and panel.tau.value == 0.42  # the slider says what the project has
    assert panel.counter.settle()
    assert panel.live_count == len(p.keyframes) and f"(project: {len(p.keyframes)})" in panel.count.value
    state.redo()
    assert panel.tau.value == 0.99
    state.edit("recluster", tau=0.3)  # another panel (or a job) re-clusters: the slider follows
    assert panel.tau.value == 0.3
    panel.tau.value = 0.5  # the artist's unapplied τ survives an edit that leaves τ alone
    state.edit("set_hold", p.keyframes[0].id, True)
    assert panel.tau.value == 0.5


def card_frame(card) -> tuple[int, int, int]:
    """The colour a person sees around a card's picture (its status frame), read from the PNG's pixels."""
    rgb = np.asarray(Image.open(io.BytesIO(bytes(card.children[0].value))).convert("RGB"))
    return tuple(int(v) for v in rgb[1, rgb.shape[1] // 2])


def test_cards_show_each_keyframes_status_and_loss_counts_and_times_in_words(state):
    from widgets.keyframes import STATUS_RGB

    p = state.project
    first, second = p.keyframes[0], p.keyframes[1]
    shadow = np.zeros(p.state.targets.shape[1:], np.uint8)
    p.set_result(first.id, np.zeros(21), {"total": 0.1234}, shadow, inputs=p.keyframe_inputs(first.id))
    p.set_result(second.id, np.zeros(21), {"total": 0.5}, shadow, inputs="another project's inputs")  # stale
    panel = KeyframesPanel(state)
    cards = {kf.id: c for kf, c in zip(p.keyframes, panel.strip.children, strict=True)}
    assert card_frame(cards[first.id]) == STATUS_RGB["current"]
    assert card_frame(cards[second.id]) == STATUS_RGB["stale"]
    assert all(card_frame(cards[kf.id]) == STATUS_RGB["missing"] for kf in p.keyframes[2:])
    assert "current" in cards[first.id].children[2].value and "loss 0.123" in cards[first.id].children[2].value
    assert "stale" in cards[second.id].children[2].value and "loss 0.500" in cards[second.id].children[2].value
    assert "missing" in cards[p.keyframes[-1].id].children[2].value
    assert "refined together" not in cards[first.id].children[2].value
    p.set_result(first.id, np.zeros(21), {"total": 0.1234}, shadow, awaits="together")  # a run stopped before it
    panel.redraw()
    card = panel.strip.children[[kf.id for kf in p.keyframes].index(first.id)]
    assert card_frame(card) == STATUS_RGB["current"] and "to be refined together" in card.children[2].value
    p.optimise_again([first.id])  # a move to another source too fast, and the run stopped before mending it: stale
    panel.redraw()
    card = panel.strip.children[[kf.id for kf in p.keyframes].index(first.id)]
    assert card_frame(card) == STATUS_RGB["stale"] and "to be optimised again" in card.children[2].value
    # plurals and times, everywhere in the panel
    text = " ".join([panel.count.value, *(c.children[2].value for c in panel.strip.children),
                     *(label for label, _ in panel.keyframe.options)])  # fmt: skip
    assert "1 frames" not in text and "1 keyframes" not in text
    lone = [kf for kf in p.keyframes if len(kf.members) == 1]
    assert all(f"k{kf.id} (1 frame)" in [lb for lb, _ in panel.keyframe.options] for kf in lone)
    panel.tau.value = 0.0
    panel.tau.value = 0.99
    state.select(frame=0, keyframe=first.id)
    panel.clock.value = False
    panel.time.value = 0.7 + 0.1  # what a browser's spinner sends: 0.7999999999999999
    assert panel.time.value == 0.8
    panel.set_time.click()
    assert p.state.keyframe(first.id).time_s == 0.8
    card = panel.strip.children[[kf.id for kf in p.keyframes].index(first.id)]
    assert "at 0.80 s" in card.children[2].value and "99999" not in card.children[2].value


def test_the_legend_names_the_colours_the_cards_paint(state):
    """Under the strip a line names each colour a card paints: the expressive region's tint and each status's frame,
    checked against the cards' pixels (a legend coloured otherwise fails)."""
    import cv2

    panel = KeyframesPanel(state)
    keys = re.findall(r"background:rgb\((\d+), (\d+), (\d+)\)\"></span>([^&<]+)", panel.legend.value)
    said = {words.strip(): tuple(int(v) for v in rgb) for *rgb, words in keys}
    assert list(said) == ["expressive region", "frame: result missing", "frame: result stale", "frame: result current"]
    card = panel.strip.children[0]  # no result yet
    assert card_frame(card) == said["frame: result missing"]
    rgb = np.asarray(Image.open(io.BytesIO(bytes(card.children[0].value))).convert("RGB"))
    hsv = cv2.cvtColor(rgb[8:-8, 8:-8], cv2.COLOR_RGB2HSV_FULL).reshape(-1, 3).astype(int)
    tinted = hsv[hsv[:, 1] > 80]  # inside the frame, the only coloured pixels are the expressive region's
    assert len(tinted) > 50, "the card paints no expressive region"

    def hue(c) -> int:
        return int(cv2.cvtColor(np.uint8([[c]]), cv2.COLOR_RGB2HSV_FULL)[0, 0, 0])

    drawn, named = int(np.median(tinted[:, 0])), hue(said["expressive region"])
    assert min(abs(drawn - named), 256 - abs(drawn - named)) <= 6, (drawn, named)  # (of 256)


def test_the_count_is_worked_out_aside_and_only_when_what_it_reads_changes(state, monkeypatch):
    """Edits that leave the clustering's inputs alone (hold, weights) cost no recount; a paint stroke recounts in the
    panel's thread: the edit returns at once, the count says "counting…" and lands when done. "Apply τ" then cuts
    the counted merge orders (no merging again) into the keyframes clustering makes at that τ."""
    import threading

    import studio.project.edits as module
    import studio.targets.keyframes as keyframes

    calls, release = [], threading.Event()
    real_embed = keyframes.embed
    release.set()
    real = module.merge_orders

    def counted(*args, **kwargs):
        calls.append(1)
        release.wait(30)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "merge_orders", counted)
    panel = KeyframesPanel(state)
    p = state.project
    try:
        assert panel.counter.settle() and len(calls) == 1
        state.edit("set_hold", p.keyframes[0].id, True)
        state.edit("set_weights", w_iou=2.0)
        panel.tau.value = 0.99
        assert panel.counter.settle() and len(calls) == 1 and panel.live_count == 9  # no recount, counted at once
        release.clear()
        edit = threading.Thread(target=state.edit, args=("paint", 0), kwargs={"additions": np.ones((48, 48), np.uint8)})
        edit.start()
        edit.join(10)
        assert not edit.is_alive(), "the paint edit waited for the recount"
        assert "counting keyframes at τ 0.990" in panel.count.value
        release.set()
        assert panel.counter.settle() and len(calls) == 2 and panel.count.value.startswith(f"{panel.live_count} ")
        embedded = []
        monkeypatch.setattr(keyframes, "embed", lambda *a, **k: embedded.append(1) or real_embed(*a, **k))
        for tau in (0.3, 0.42):
            panel.tau.value = tau
            panel.apply_tau.click()
            assert len(calls) == 2 and not embedded, "Apply τ clustered the frames again"
            want = cluster_keyframes(p.combined_masks(), KeyframeConfig(tau=tau), p.state.targets)
            embedded.clear()
            assert [kf.members for kf in p.keyframes] == [tuple(m) for m in want.members]
            assert [kf.representative for kf in p.keyframes] == want.representatives.tolist()
            assert len(p.keyframes) == panel.live_count and f"(project: {panel.live_count})" in panel.count.value
        state.undo()  # back to the painted state at τ 0.3: its merge orders are still kept
        assert panel.counter.settle() and len(calls) == 2 and p.state.clustering.tau == 0.3
    finally:
        release.set()
        panel.close()
