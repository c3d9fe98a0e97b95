"""The Masks panel driven from Python: its frame picker selects the frame in every tab and the picture drawn follows
it; strokes through the canvas panel's API (and its mouse callbacks) end in the project's paint PNGs, erasures and
additions apart; clear and undo."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from studio.assets import asset

from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.targets.video import VideoConfig
from widgets.images import upscale
from widgets.masks import MasksPanel, masks_panel
from widgets.state import StudioState
from widgets.targets import TargetsPanel

S = 64  # the project's square frame, px
SIDE = 256  # the canvas, px: 4 canvas px per mask px


@pytest.fixture
def state(tmp_path):
    project = Project.create(tmp_path / "m.shadow", [Path(asset("targets/asl_o.jpeg"))], video=VideoConfig(size=S))
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


@pytest.fixture
def horse(tmp_path):
    """The bundled horse clip: five frames, each its own shape."""
    project = Project.create(tmp_path / "h.shadow", [Path(asset("videos/muybridge_horse.gif"))],
                             video=VideoConfig(size=S))  # fmt: skip
    s = StudioState(project, queue_for(project))
    yield s
    s.close()


def png_layer(project: Project, prefix: str) -> np.ndarray | None:
    found = sorted((project.path / "masks").glob(f"{prefix}-*.png"))
    return None if not found else (np.array(Image.open(found[-1])) != 0).astype(np.uint8)


def test_title_and_the_expressive_mask_over_the_target(state):
    widget = masks_panel(state)
    assert "Masks" in widget.children[0].value
    panel = MasksPanel(state, side=SIDE)
    pic = panel.picture()
    assert pic.shape == (SIDE, SIDE, 3)
    auto = state.project.state.auto[0]
    assert auto.any()
    y, x = np.argwhere(auto)[0] * (SIDE // S)
    assert not (pic[y, x] == pic[y, x, 0]).all()  # the automatic mask is tinted (not grey)


def test_the_frame_picker_selects_the_frame_in_every_tab_and_the_picture_follows(horse):
    targets = horse.project.state.targets
    panel, other = MasksPanel(horse, side=SIDE), TargetsPanel(horse)
    drawn: list[np.ndarray] = []  # every picture the panel puts on its canvas
    put = panel.paint.put
    panel.paint.put = lambda rgb: (drawn.append(np.array(rgb)), put(rgb))

    def shape_drawn() -> np.ndarray:  # the target's dark shape in the last picture drawn (orange tint or not)
        return drawn[-1].astype(float).mean(axis=2) < 128

    def like(f: int) -> float:  # IoU of the shape drawn with frame f's target at the canvas's size
        want = upscale(targets[f], SIDE) > 0
        return float((shape_drawn() & want).sum() / (shape_drawn() | want).sum())

    try:
        assert panel.frame_picker in panel.widget.children and panel.frame_picker.max == len(targets) - 1
        panel.frame_picker.value = 3
        assert horse.selection.frame == 3 and other.scrubber.value == 3  # selected in every tab
        assert drawn and like(3) > 0.95 and like(0) < 0.8  # the picture is frame 3's, not the one before
        horse.select(frame=1)  # picked elsewhere (the strip, another tab): the picker and the picture follow
        assert panel.frame_picker.value == 1 and like(1) > 0.95 and like(3) < 0.8
    finally:
        panel.close()
        other.close()


def test_strokes_are_saved_as_the_paint_pngs_and_undo(state):
    panel = MasksPanel(state, side=SIDE)
    p = state.project
    assert png_layer(p, "add") is None
    panel.stroke([(20, 20), (100, 20)], radius=8, mode="add")  # a bar 5..25 canvas px tall → mask rows 3..6
    add = p.state.additions["0:0"]
    rows, cols = np.nonzero(add)
    assert add[5, 5:25].all() and 1 <= rows.min() <= rows.max() <= 8 and 1 <= cols.min() <= cols.max() <= 28
    assert np.array_equal(png_layer(p, "add"), add)  # on disk, as its own PNG
    assert np.array_equal(Project.open(p.path).state.additions["0:0"], add)
    panel.stroke([(40, 20)], radius=4, mode="erase")  # a dab in the bar: erased, and the addition taken back there
    erase = p.state.erasures["0:0"]
    assert erase[5, 10] and not p.state.additions["0:0"][5, 10] and p.state.additions["0:0"][5, 20]
    assert np.array_equal(png_layer(p, "erase"), erase)
    combined = p.combined_masks()[0]
    assert not combined[5, 10] and combined[5, 20]
    panel.undo.click()
    assert "0:0" not in p.state.erasures and np.array_equal(p.state.additions["0:0"], add)
    panel.clear.click()
    assert not p.state.additions and not p.state.erasures
    panel.undo.click()
    assert np.array_equal(p.state.additions["0:0"], add)


def test_the_mouse_callbacks_paint_one_stroke_with_the_brush_settings(state):
    panel = MasksPanel(state, side=SIDE)
    panel.brush.value = 4
    panel.mode.value = "erase"
    panel.mouse_down(200, 200)
    panel.mouse_move(210, 200)
    panel.mouse_move(220, 200)
    assert not state.project.state.erasures  # saved on release only
    panel.mouse_up(230, 200)
    erase = state.project.state.erasures["0:0"]
    assert erase[50, 50:57].all() and not erase[:40].any()
    assert state.project.history[-1].startswith("paint frame 0") and len(state.project.history) == 1
    panel.mouse_up(0, 0)  # a stray release paints nothing
    assert len(state.project.history) == 1


def test_a_bad_mode_is_refused_and_the_mouse_shows_it(state):
    panel = MasksPanel(state, side=SIDE)
    with pytest.raises(Exception, match="add' or 'erase"):
        panel.stroke([(1, 1)], 2, mode="smudge")
    panel.mode.value = "add"
    panel.mouse_down(1, 1)
    state.project.paint(0, additions=np.ones((S, S), np.uint8))  # fine: the panel re-reads the layer
    panel.mouse_up(2, 2)
    assert panel.messages.text == "" and state.project.state.additions["0:0"].all()


def test_the_brush_is_an_ipycanvas_canvas_wired_to_the_mouse(state):
    ipycanvas = pytest.importorskip("ipycanvas")
    panel = MasksPanel(state, side=SIDE)
    assert isinstance(panel.canvas, ipycanvas.Canvas) and panel.canvas in panel.widget.children[2].children
    assert panel.canvas.width == SIDE and panel.canvas.height == SIDE
    for event, x in (("mouse_down", 40), ("mouse_move", 60), ("mouse_up", 80)):  # what the browser sends
        panel.canvas._handle_frontend_event(panel.canvas, {"event": event, "x": x, "y": 40}, [])
    add = state.project.state.additions["0:0"]
    assert add[10, 10:20].all() and len(state.project.history) == 1


def test_a_closed_panel_stops_following_the_state(state):
    panel = MasksPanel(state, side=SIDE)
    panel.close()
    state.edit("paint", 0, additions=np.ones((S, S), np.uint8))
    assert "painted" not in panel.info.value


def test_the_legend_names_the_colours_the_picture_paints(state):
    """Under the picture a line names each colour: the expressive region, painted in, painted out. Each legend square
    has the hue of what the picture draws there (a legend coloured the other way round fails)."""
    panel = MasksPanel(state, side=SIDE)
    panel.stroke([(20, 20), (100, 20)], radius=8, mode="add")  # painted in: mask rows 3..6, columns 3..26
    panel.stroke([(200, 200)], radius=8, mode="erase")  # painted out: around mask px (50, 50)
    pic = panel.picture()
    keys = re.findall(r"background:rgb\((\d+), (\d+), (\d+)\)\"></span>([^&<]+)", panel.legend.value)
    said = {words.strip(): tuple(int(v) for v in rgb) for *rgb, words in keys}
    assert list(said) == ["expressive region (the Exp. terms weigh it)", "painted in", "painted out"]
    assert "drag on the frame to paint" in panel.legend.value

    def hue(rgb) -> float:
        return float(cv2.cvtColor(np.uint8([[rgb]]), cv2.COLOR_RGB2HSV_FULL)[0, 0, 0])

    def hue_gap(a: float, b: float) -> float:
        return min(abs(a - b), 256 - abs(a - b))

    auto = state.project.combined_mask(0) & ~state.project.state.additions["0:0"].astype(bool)
    y, x = np.argwhere(auto)[len(np.argwhere(auto)) // 2] * (SIDE // S) + SIDE // S // 2
    for (py, px), words in (((y, x), "expressive region (the Exp. terms weigh it)"), ((20, 60), "painted in"),
                            ((200, 200), "painted out")):  # fmt: skip
        drawn = pic[py, px]
        assert drawn.max() - drawn.min() > 40, f"{words}: the picture draws grey {drawn} there"
        gaps = {name: hue_gap(hue(drawn), hue(rgb)) for name, rgb in said.items()}
        assert min(gaps, key=gaps.get) == words, (words, drawn, gaps)
