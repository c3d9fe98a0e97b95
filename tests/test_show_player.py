"""The show preview's player and frame strip (widgets.show_player), in Python and in JupyterLab's headless Chromium:
the player gets every frame at ≥ 20 fps and follows the selection, a click on the strip selects the frame under it,
an edit never waits for the strip, the Review panel holds them; in the browser the canvas shows the preview's
pixels, plays at ≥ 20 frames a second, and a click on the strip moves the player."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from preview_support import dark, planned_horse

from studio.project.jobs import queue_for
from studio.project.preview import PreviewConfig, frame_strip, preview_inputs, render_preview
from studio.project.project import Project
from studio.review.preview import decode_image
from studio.review.preview_strips import timeline_image
from studio.review.sheets import tint
from widgets.state import StudioState


@pytest.fixture(scope="module")
def planned(tmp_path_factory, hand):
    """The horse planned and previewed (preview_support.planned_horse)."""
    return planned_horse(tmp_path_factory.mktemp("preview"), hand)


@pytest.fixture
def panel(planned):
    from widgets.show_player import ShowPreviewPanel

    project = planned[0]
    state = StudioState(project, queue_for(project))
    panel = ShowPreviewPanel(state)
    assert panel.refresher.settle() and panel.job is not None and panel.job.wait(60).value == "done"
    yield panel
    panel.close()
    state.close()


def test_the_player_gets_every_frame_at_20_fps_or_more_and_follows_the_selection(panel, planned):
    preview = panel.preview
    player = panel.player
    assert preview is not None and preview.frames == planned[1].frames  # a video: no move from home to add
    assert player.frame_count == len(preview.frames) == len(planned[1].frames) and player.fps >= 20
    assert player.frame(0) == preview.frames[0] and player.frame(player.frame_count - 1) == preview.frames[-1]
    assert player.times == pytest.approx(list(preview.clock.times)) and player.loop and player.speed == 1.0
    assert np.array_equal(decode_image(player.timeline), timeline_image(preview.clock, panel.timeline_px))
    # the same content is never rendered twice
    jobs = len(panel.state.queue.jobs())
    panel.refresh()
    assert len(panel.state.queue.jobs()) == jobs
    # the browser pausing on a frame selects it in every tab; a selection elsewhere moves the player there
    m = len(preview.frames) - 1
    player.index = m
    assert panel.state.selection.frame == int(preview.clock.frame[m])
    panel.state.select(frame=1)
    assert int(preview.clock.frame[player.index]) == 1 and panel.strip.selected == 1


def test_a_click_on_the_strip_selects_the_frame_under_it(panel):
    project, strip = panel.state.project, panel.strip
    picture = decode_image(strip.image)
    img, boxes = frame_strip(project)
    assert np.array_equal(picture, img) and strip.boxes == [list(b) for b in boxes]
    frame = 3
    x, y, _, h = boxes[frame]
    target = tint(project.state.targets[frame], project.combined_masks()[frame], h)
    ys, xs = np.nonzero(dark(target)[20:])  # a shape pixel, below the label
    py, px = int(ys[len(ys) // 2]) + 20, int(xs[len(xs) // 2])
    assert np.array_equal(picture[y + py, x + px], target[py, px])  # the strip shows frame 3's target there
    strip._message(strip, {"type": "click", "x": x + px + 0.5, "y": y + py + 0.5}, [])  # what the browser sends
    assert panel.state.selection.frame == frame and strip.selected == frame
    assert strip.click(boxes[0][0] + boxes[0][2] + 2, 5) is None  # the gap between two cells names no frame
    assert panel.state.selection.frame == frame


def test_an_edit_never_waits_for_the_strip_and_the_strip_shows_the_edit(panel, monkeypatch):
    """The strip (every frame drawn) and the preview's content hash are worked out in the panel's thread: with the
    strip's drawing held, a paint edit returns at once, and the strip then shows the painted mask."""
    import widgets.show_player as module

    release, held, real = threading.Event(), threading.Event(), module.frame_strip

    def held_strip(*args, **kwargs):
        held.set()
        release.wait(30)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, "frame_strip", held_strip)
    state, before = panel.state, decode_image(panel.strip.image)
    painted = np.ones(state.project.state.auto.shape[1:], np.uint8)
    edit = threading.Thread(target=state.edit, args=("paint", 0), kwargs={"additions": painted})
    try:
        edit.start()
        assert held.wait(10)  # the strip is being drawn for the edit, in the panel's thread
        edit.join(10)
        assert not edit.is_alive(), "the edit waited for the strip"
    finally:
        release.set()
    assert panel.refresher.settle()
    after = decode_image(panel.strip.image)
    assert np.array_equal(after, real(state.project)[0]) and not np.array_equal(after, before)


def test_the_review_panel_shows_the_preview_and_picks_frames(planned, tmp_path):
    from widgets.review import ReviewConfig, review_panel

    project = planned[0]
    state = StudioState(project, queue_for(project))
    panel = review_panel(state, ReviewConfig(rrd=tmp_path / "review.rrd", viewer=False, scene=False))
    try:
        assert panel.preview.widget in panel.widget.children and panel.frame_picker in panel.widget.children
        assert panel.frame_picker.max == len(project.frames) - 1
        panel.frame_picker.value = 2
        assert state.selection.frame == 2 and panel.shown_frame == 2 and panel.preview.strip.selected == 2
        state.select(frame=4)
        assert panel.frame_picker.value == 4
    finally:
        panel.close()
        state.close()


BROWSER_CELL = """
from studio.project.jobs import queue_for
from studio.project.project import Project
from widgets.show_player import ShowPreviewPanel
from widgets.state import StudioState
project = Project.open({path!r})
panel = ShowPreviewPanel(StudioState(project, queue_for(project)))
panel.refresher.settle(60)
panel.job.wait(120)
panel.widget
"""
PLAYER = "document.querySelector('.show-player')"


@pytest.fixture
def lab_on(tmp_path):
    """``lab_on(code)`` → the URL of a notebook running ``code`` in a fresh JupyterLab (stopped after the test)."""
    import json
    import os
    import secrets
    import signal
    import subprocess
    import sys
    import time
    import urllib.request

    import nbformat

    from studio.cli.lab import free_port

    procs = []

    def start(code: str) -> str:
        nb = nbformat.v4.new_notebook(cells=[nbformat.v4.new_code_cell(code)])
        nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
        nbformat.write(nb, tmp_path / "player.ipynb")
        (tmp_path / "config" / "labconfig").mkdir(parents=True)
        off = {"disabledExtensions": {"@jupyterlab/apputils-extension:announcements": True}}
        (tmp_path / "config" / "labconfig" / "page_config.json").write_text(json.dumps(off))
        env = os.environ | {"JUPYTER_CONFIG_DIR": str(tmp_path / "config"),
                            "JUPYTER_RUNTIME_DIR": str(tmp_path / "runtime")}  # fmt: skip
        token, port = secrets.token_hex(8), free_port(18950)
        procs.append(subprocess.Popen(
            [sys.executable, "-m", "jupyter", "lab", "--no-browser", f"--port={port}", "--ServerApp.ip=127.0.0.1",
             f"--ServerApp.token={token}", "--allow-root", "--LabApp.expose_app_in_browser=True",
             f"--notebook-dir={tmp_path}"], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
            start_new_session=True))  # fmt: skip
        for _ in range(240):
            try:
                urllib.request.urlopen(f"http://127.0.0.1:{port}/api/status?token={token}", timeout=1)
                break
            except OSError:
                time.sleep(0.5)
        return f"http://127.0.0.1:{port}/lab/tree/player.ipynb?token={token}"

    yield start
    for proc in procs:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            proc.wait(30)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)


@pytest.mark.slow
def test_the_player_plays_in_the_browser_and_the_strip_selects(planned, lab_on):
    """In JupyterLab (headless Chromium): the player's canvas shows the preview's pixels, plays at ≥ 20 frames a
    second, and a click on the strip's cell of frame 3 moves the player to where frame 3 plays."""
    from browser_page import CHROMIUM, CHROMIUM_FLAGS, KERNEL_IDLE, playwright_api

    from hardware.player import PlayerConfig

    sync_playwright = playwright_api()
    project = planned[0]
    preview = render_preview(preview_inputs(project), PreviewConfig(home=PlayerConfig().ramp_speed_rad_s))
    url = lab_on(BROWSER_CELL.format(path=str(project.path)))
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_FLAGS)
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        page.wait_for_function(KERNEL_IDLE, timeout=120_000)
        page.evaluate("() => window.jupyterapp.commands.execute('notebook:run-all-cells')")
        page.wait_for_function(f"() => {{ const r = {PLAYER}; return r && r.dataset.painted !== undefined; }}",
                               timeout=180_000)  # fmt: skip
        shown = page.evaluate(f"""() => {{ const c = {PLAYER}.querySelector('canvas');
            return [Number({PLAYER}.dataset.painted), c.width, c.height,
                    Array.from(c.getContext('2d').getImageData(0, 0, c.width, c.height).data)]; }}""")
        m, width, height = shown[:3]
        pixels = np.array(shown[3], np.uint8).reshape(height, width, 4)[..., :3]
        assert np.abs(pixels.astype(float) - decode_image(preview.frames[m])).mean() < 3  # what was rendered
        page.locator(".show-player button").first.click()  # play
        rates = []  # frames drawn a second, over each second of playing (a shared machine may hiccup in one)
        for _ in range(3):
            page.wait_for_timeout(1500)
            rates.append(float(page.evaluate(f"() => {PLAYER}.dataset.fps || 0")))
        assert max(rates) >= 20, f"the player drew {rates} frames a second"
        page.locator(".show-player button").first.click()  # pause
        strip = page.locator(".frame-strip canvas").first
        box = strip.bounding_box()
        natural = page.evaluate("() => document.querySelector('.frame-strip canvas').width")
        x, y, w, h = cell_boxes_of(project)[3]
        scale = box["width"] / natural
        strip.click(position={"x": (x + w / 4) * scale, "y": (y + h / 2) * scale})
        first = int(np.flatnonzero(preview.clock.frame == 3)[0])
        page.wait_for_function(f"() => Number({PLAYER}.dataset.frame) === {first}", timeout=30_000)
        browser.close()
    assert not errors, errors


def cell_boxes_of(project: Project) -> list[tuple[int, int, int, int]]:
    return frame_strip(project)[1]
