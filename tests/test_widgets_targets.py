"""The Targets panel driven from Python: add sources (sample, path, upload), scrub, sample, threshold with its
live preview, and segment raw colour footage as a job; every edit undoable."""

from __future__ import annotations

from datetime import datetime, timezone
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from studio.assets import asset
from targets_panel_support import STILL, finished, one_still_state  # the Targets panel tests' helpers

from studio.jobs import JobState
from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.targets.images import TargetConfig, crop_square
from studio.targets.video import DEFAULT_VIDEO, VideoConfig
from widgets.images import ADD_RGB
from widgets.keyframes import KeyframesPanel
from widgets.masks import MasksPanel
from widgets.state import StudioState
from widgets.targets import TargetsPanel, targets_panel


@pytest.fixture
def state(tmp_path):
    with one_still_state(tmp_path) as s:
        yield s


def labels(widget) -> str:
    out, todo = [], [widget]
    while todo:
        x = todo.pop()
        out.append(str(getattr(x, "value", "")) if hasattr(x, "value") else "")
        todo.extend(getattr(x, "children", ()))
    return " ".join(o for o in out if isinstance(o, str))


def test_the_panel_has_its_title_and_adds_a_bundled_video(state):
    assert "Targets" in labels(targets_panel(state))
    panel = TargetsPanel(state)
    others = KeyframesPanel(state), MasksPanel(state)  # they follow the scrubber and redraw after every edit
    assert panel.drawer.settle() and panel.scrubber.max == 0 and panel.preview.value  # one still, previewed
    panel.sample.value = "muybridge_horse.gif"
    panel.add_sample.click()
    finished(panel)
    assert panel.messages.text == ""
    assert [s.kind for s in state.project.sources] == ["still", "video"]
    n = len(state.project.frames)
    assert n > 2 and panel.scrubber.max == n - 1
    assert state.selection.frame == 1  # the new source's first frame is in view
    panel.scrubber.value = n - 1
    assert state.selection.frame == n - 1 and "source 1" in panel.frame_info.value
    panel.hz.value = 1.0
    panel.apply_hz.click()
    finished(panel)
    assert state.project.state.video.hz == 1.0 and len(state.project.frames) < n
    state.undo()
    assert len(state.project.frames) == n and panel.hz.value == 2.0
    assert others[1].info.value.startswith(f"frame {state.selection.frame}") and state.selection.frame > 0
    state.undo()
    assert len(state.project.sources) == 1 and panel.scrubber.max == 0
    assert state.selection.frame == 0 and others[1].info.value.startswith("frame 0")
    assert len(others[0].strip.children) == len(state.project.keyframes)


def test_a_missing_path_is_a_message_not_a_traceback(state, tmp_path):
    panel = TargetsPanel(state)
    panel.path.value = str(tmp_path / "nowhere.png")
    panel.add_path.click()
    assert "no such file" in panel.messages.text and len(state.project.sources) == 1


def test_an_upload_is_written_into_the_project_and_added(state):
    panel = TargetsPanel(state)
    data = Path(asset("targets/asl_v.jpeg")).read_bytes()
    panel.upload.value = ({"name": "my_v.jpeg", "type": "image/jpeg", "size": len(data), "content": memoryview(data),
                           "last_modified": datetime.now(timezone.utc)},)  # fmt: skip
    finished(panel)
    assert panel.messages.text == ""
    written = state.project.path / "uploads" / "my_v.jpeg"
    assert written.read_bytes() == data
    assert Path(state.project.sources[-1].absolute) == written.resolve() and len(state.project.frames) == 2


def test_threshold_preview_follows_the_slider_and_otsu_then_applies(state):
    panel = TargetsPanel(state)
    panel.threshold.value = 5.0
    panel.refresh_preview()  # the throttled redraw, now
    low = panel.preview_mask.sum()
    assert panel.preview_level == 5.0
    panel.threshold.value = 200.0
    panel.refresh_preview()
    assert panel.preview_mask.sum() < low
    panel.otsu.value = True
    panel.refresh_preview()
    assert 5.0 < panel.preview_level < 250.0 and panel.threshold.disabled
    before = state.project.state.targets.copy()
    panel.apply_threshold.click()
    finished(panel)
    assert state.project.state.still.threshold is None and panel.messages.text == ""
    panel.otsu.value = False
    panel.threshold.value = 100.0
    panel.apply_threshold.click()
    finished(panel)
    assert state.project.state.still.threshold == 100.0, panel.messages.text
    assert not np.array_equal(state.project.state.targets, before)
    state.undo()
    state.undo()
    assert state.project.state.still.threshold == TargetConfig().threshold
    assert np.array_equal(state.project.state.targets, before)


def colour_clip(folder: Path, seed: int) -> Path:
    """Four 80 × 64 frames of a red square moving right over a noisy green ground (raw colour footage)."""
    folder.mkdir()
    rng = np.random.default_rng(seed)
    ground = (rng.integers(0, 40, (64, 80, 3)) + np.array([40, 140, 60])).astype(np.uint8)
    for i in range(4):
        frame = ground.copy()
        frame[20:44, 10 + 6 * i : 34 + 6 * i] = (220, 40, 40)
        Image.fromarray(frame).save(folder / f"{i:05d}.png")
    return folder


def test_raw_colour_footage_waits_for_a_box_then_is_segmented_as_a_job(state, tmp_path):
    folder = colour_clip(tmp_path / "colour", seed=3)
    panel = TargetsPanel(state)
    panel.path.value = str(folder)
    panel.add_path.click()
    finished(panel)  # the footage was read: colour, not a shadow
    assert panel.pending == folder and "colour footage" in panel.messages.text
    assert len(state.project.sources) == 1
    assert [t.value for t in panel.box] == [20, 16, 40, 32]  # a first guess: the middle of the 80 × 64 frame
    for t, v in zip(panel.box, (8, 18, 28, 28), strict=True):
        t.value = v
    panel.refresh_preview()  # the first frame with the box drawn (80 px → 256 px: × 3.2)
    assert tuple(panel.preview_rgb[int(18 * 3.2) + 1, 50]) == (255, 170, 0)  # its top edge
    assert tuple(panel.preview_rgb[100, 150]) != (255, 170, 0)
    for t, v in zip(panel.box, (500, 500, 10, 10), strict=True):  # nowhere near the shape
        t.value = v
    panel.segment.click()
    assert panel.job.wait(60) == JobState.FAILED and len(state.project.sources) == 1
    assert "segment colour failed" in panel.messages.text and "outside" in panel.messages.text
    assert "failed" in panel.job_info.value and "Error" not in panel.messages.text
    assert panel.pending == folder
    for t, v in zip(panel.box, (8, 18, 28, 28), strict=True):
        t.value = v
    panel.segment.click()
    finished(panel)
    assert panel.job_info.value.endswith("done") and panel.cancel_job.disabled and not panel.segment.disabled
    src = state.project.sources[-1]
    assert src.footage == "segmented" and src.box == (8, 18, 28, 28) and panel.pending is None
    assert "segmented" in panel.sources.value
    state.undo()
    assert len(state.project.sources) == 1


def test_raw_footage_segmented_from_a_mask_painted_on_its_first_frame(state, tmp_path):
    folder = colour_clip(tmp_path / "colour", seed=5)
    panel = TargetsPanel(state)
    panel.path.value = str(folder)
    panel.add_path.click()
    finished(panel)
    first = panel.first
    assert panel.pending == folder and first.widget.layout.display is None
    with pytest.raises(Exception, match="paint the object"):
        first.given.value = "mask"
        first.prompt()
    # a drag over the square (source px (12..30, 24..40) → canvas × 3.2), then a smaller erase at its far corner
    first.brush.value = 12  # a mouse drag over it, as the canvas reports one
    first.paint.mouse_down(14 * 3.2, 26 * 3.2)
    first.paint.mouse_move(22 * 3.2, 32 * 3.2)
    first.paint.mouse_up(30 * 3.2, 38 * 3.2)
    assert first.given.value == "mask" and first.mask[30, 20] == 1 and first.mask[5, 70] == 0
    painted = int(first.mask.sum())
    first.stroke([(30 * 3.2, 38 * 3.2)], radius=3, mode="erase")
    assert 0 < first.mask.sum() < painted and first.mask[38, 30] == 0
    # what the artist sees: the paint tinted green over the frame, the ground untouched
    inside, outside = panel.preview_rgb[int(30 * 3.2), int(20 * 3.2)], panel.preview_rgb[int(5 * 3.2), int(70 * 3.2)]
    plain = crop_square(np.asarray(Image.open(folder / "00000.png")), (0, 0, 80, 80), 256)
    plain = np.clip(plain, 0, 255).astype(np.uint8)
    green = np.array(ADD_RGB)
    under = plain[int(30 * 3.2), int(20 * 3.2)].astype(int)
    assert np.abs(inside.astype(int) - green).sum() < np.abs(under - green).sum() - 100  # tinted towards green
    assert tuple(outside) == tuple(plain[int(5 * 3.2), int(70 * 3.2)])
    panel.segment.click()
    finished(panel)
    src = state.project.sources[-1]
    assert src.footage == "segmented" and src.box is None and src.first_mask is not None
    assert panel.pending is None and first.widget.layout.display is None  # shown to segment it again
    # the painted mask started it and the segmentation followed the square (its last frame: columns 28..52)
    last = [i for i, f in enumerate(state.project.frames) if f.source == len(state.project.sources) - 1][-1]
    assert state.project.state.targets[last].any()


def test_a_moved_source_is_relinked_from_the_panel_and_names_are_never_markup(tmp_path):
    src = tmp_path / "<img src=x>.jpeg"
    src.write_bytes(STILL.read_bytes())
    project = Project.create(tmp_path / "m.shadow", [src], video=VideoConfig(size=48, hz=2.0))
    moved = tmp_path / "moved.jpeg"
    src.rename(moved)
    s = StudioState.open(project.path)
    try:
        panel = TargetsPanel(s)
        assert panel.relink.widget.layout.display == "" and "source 0 is missing" in panel.relink.line.value
        assert "<img" not in panel.sources.value and "&lt;img src=x&gt;" in panel.sources.value
        assert "<img" not in panel.relink.line.value
        panel.relink.path.value = str(tmp_path / "nowhere.jpeg")
        panel.relink.button.click()
        assert "source not found" in panel.messages.text and s.project.missing_sources
        panel.relink.path.value = str(moved)
        panel.relink.button.click()
        finished(panel)
        assert "relinked" in panel.messages.text and not panel.relink.path.value
        assert not s.project.missing_sources and panel.relink.widget.layout.display == "none"
        assert Project.open(project.path).sources[0].absolute == str(moved) and s.project.can_undo
    finally:
        s.close()


def test_an_upload_never_follows_a_planted_link_nor_overwrites_a_file(state, tmp_path):
    panel = TargetsPanel(state)
    uploads = state.project.path / "uploads"
    uploads.mkdir()
    victim = tmp_path / "victim.txt"
    victim.write_text("mine")
    (uploads / "o.jpeg").symlink_to(victim)
    data = STILL.read_bytes()
    panel.upload.value = ({"name": "o.jpeg", "type": "image/jpeg", "size": len(data), "content": memoryview(data),
                           "last_modified": datetime.now(timezone.utc)},)  # fmt: skip
    finished(panel)
    assert victim.read_text() == "mine" and (uploads / "o-2.jpeg").read_bytes() == STILL.read_bytes()
    assert len(state.project.sources) == 2


def tinted(rgb: np.ndarray) -> np.ndarray:
    """The pixels a person sees tinted with the mask colour (orange: red well above blue; a grey frame has R = B)."""
    a = rgb.astype(int)
    return (a[..., 0] - a[..., 2]) > 40


def test_the_horse_preview_tints_the_horse_not_its_backdrop_and_shows_what_is_stored(tmp_path):
    """The bundled horse is a dark shape on a light ground, framed with black bars: the preview must tint the horse
    (where the project's saved mask is) at the project's threshold, a stricter one and Otsu's, never the backdrop;
    the second picture is the mask the project stores after its cleanup."""
    project = Project.create(tmp_path / "h.shadow", [DEFAULT_VIDEO], video=VideoConfig(size=48, hz=2.0))
    s = StudioState(project, queue_for(project))
    try:
        panel = TargetsPanel(s)
        assert panel.drawer.settle()
        panel._throttled = lambda: None  # draw only when asked: no drawing thread racing the drawing below
        side = panel.preview_rgb.shape[0]
        for frame in range(len(project.frames)):
            s.select(frame=frame)
            saved = project.state.targets[frame]
            horse = cv2.resize(saved, (side, side), interpolation=cv2.INTER_NEAREST).astype(bool)
            for otsu, level in ((False, 128.0), (False, 160.0), (True, None)):
                panel.otsu.value = otsu
                if level is not None:
                    panel.threshold.value = level
                panel.refresh_preview()
                seen = tinted(panel.preview_rgb)
                assert seen.sum() > 0.02 * seen.size, (frame, otsu, level)
                assert (seen & horse).sum() > 0.7 * seen.sum(), (frame, otsu, level)  # on the horse …
                assert seen[~horse].mean() < 0.05, (frame, otsu, level)  # … not on the backdrop nor the bars
            panel.otsu.value = False
            panel.threshold.value = 128.0  # the project's threshold: the stored picture is the saved mask
            panel.refresh_preview()
            stored = tinted(panel.stored_rgb).astype(np.float32)
            at_size = cv2.resize(stored, saved.shape[::-1], interpolation=cv2.INTER_AREA) >= 0.5
            iou = (at_size & (saved > 0)).sum() / (at_size | (saved > 0)).sum()
            assert iou > 0.95, (frame, iou)
            assert "found a dark shape on a light ground" in panel.stored_info.value  # the studio read it
    finally:
        s.close()


def test_counts_and_times_read_as_a_person_writes_them(state):
    panel = TargetsPanel(state)
    assert "(still, still, 1 frame)" in panel.sources.value  # never "1 frames"
    assert panel.frame_info.value.endswith("0.00 s")
    panel.sample.value = "muybridge_horse.gif"
    panel.add_sample.click()
    finished(panel)
    state.select(frame=len(state.project.frames) - 1)
    t = state.project.frames[-1].time_s
    assert panel.frame_info.value.endswith(f"{t:.2f} s") and "99999" not in panel.frame_info.value


def side_lit_still(path: Path) -> Path:
    """A bright hand (grey 200) on a black cut-out backdrop whose palm holds a crease's shade (grey 15, a few black
    pixels) opening to the outside through a neck on the right: thresholding cuts it out as a notch."""
    g = np.zeros((300, 300), np.uint8)
    g[120:260, 60:240] = 200  # palm
    g[30:120, 70:120] = g[30:120, 170:220] = 200  # two fingers, a true-black gap between them
    g[150:200, 100:200] = 15  # the crease's shade …
    g[150:152, 150:200] = 2
    g[170:178, 200:240] = 15  # … and its neck to the outside
    cv2.imwrite(str(path), g)
    return path


def test_a_still_s_crease_pockets_are_previewed_then_applied_and_undone(tmp_path):
    """The checkbox shows in the stored picture what filling a still's crease pockets does (the palm's shade tinted
    as skin, or cut out as a notch), applies it as one undoable edit, and is off for footage, which fills none."""
    still = side_lit_still(tmp_path / "side_lit.png")
    project = Project.create(tmp_path / "p.shadow", [still, DEFAULT_VIDEO], video=VideoConfig(size=64, hz=2.0))
    s = StudioState(project, queue_for(project))
    try:
        panel = TargetsPanel(s)
        assert panel.drawer.settle()
        panel._throttled = lambda: None  # draw only when asked
        s.select(frame=next(i for i, f in enumerate(project.frames) if f.source == 0))
        assert panel.pockets.value and not panel.pockets.disabled
        side = panel.stored_rgb.shape[0]
        at = (slice(155 * side // 300, 195 * side // 300), slice(105 * side // 300, 195 * side // 300))  # the shade
        finger_gap = (slice(40 * side // 300, 110 * side // 300), slice(125 * side // 300, 165 * side // 300))
        panel.refresh_preview()
        filled = tinted(panel.stored_rgb)
        assert filled[at].mean() > 0.95 and filled[finger_gap].mean() < 0.05  # skin; the black gap stays open
        panel.pockets.value = False
        panel.refresh_preview()
        kept = tinted(panel.stored_rgb)
        assert kept[at].mean() < 0.05 and kept.sum() < filled.sum()  # the notch, as the threshold cuts it
        before = project.state.targets.copy()
        panel.apply_threshold.click()
        finished(panel)
        assert panel.messages.text == "" and project.state.still.pocket_reach == 0.0 and not panel.pockets.value
        assert project.history[-1] == "crease pockets kept"
        frame = next(i for i, f in enumerate(project.frames) if f.source == 0)
        assert project.state.targets[frame].sum() < before[frame].sum()  # the stored mask lost the pocket
        s.undo()
        assert project.state.still.pocket_reach > 0 and np.array_equal(project.state.targets, before)
        assert panel.pockets.value
        panel.threshold.value, panel.pockets.value = 100.0, False  # both at once: one edit, one reading of the sources
        n = len(project.history)
        panel.apply_threshold.click()
        finished(panel)
        assert project.state.still.threshold == 100.0 and project.state.still.pocket_reach == 0.0
        assert len(project.history) == n + 1 and project.history[-1].endswith("; crease pockets kept")
        s.undo()
        assert project.state.still.pocket_reach > 0 and np.array_equal(project.state.targets, before)
        s.select(frame=next(i for i, f in enumerate(project.frames) if f.source == 1))
        assert panel.pockets.disabled
    finally:
        s.close()
