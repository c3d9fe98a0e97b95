"""The show preview (studio.project.preview, studio.review.preview, widgets.show_player), checked on its pixels: the
frames show the source, the target in the studio's colours and the planned show's shadow as mounted, changing with
the poses; the timeline's ticks wear their keyframe's status colour and late transitions are shaded; a click on the
strip selects the frame under it; the player gets every frame at ≥ 20 fps; a still's preview moves from home and
holds the pose."""

from __future__ import annotations

import threading
from dataclasses import replace

import numpy as np
import pytest
from studio.assets import asset

from studio.motion.plan import PlanConfig, plan_show
from studio.motion.timing import TimingConfig
from studio.project.jobs import queue_for
from studio.project.preview import PreviewConfig, frame_strip, preview_inputs, render_preview
from studio.project.preview_clock import preview_clock
from studio.project.project import Project
from studio.project.sources import framed_frames
from studio.review.preview import decode_image
from studio.review.preview_strips import LATE_RGB, STATUS_RGB, timeline_image, timeline_x
from studio.review.sheets import BACKDROP, fit_tile, tint
from studio.sim.shadow import Rig, ShadowRenderer
from studio.targets.video import VideoConfig
from widgets.images import png
from widgets.state import StudioState

TILE = 160  # the preview's column side (PreviewConfig's default)
ROLL_DEG = 25.0  # the project's mount roll: the preview's shadows must be rendered with it
COLUMNS = {"source": slice(0, TILE), "target": slice(TILE + 4, 2 * TILE + 4), "shadow": slice(2 * TILE + 8, None)}


def column(rgb: np.ndarray, name: str) -> np.ndarray:
    return rgb[:, COLUMNS[name]]


def dark(rgb: np.ndarray) -> np.ndarray:
    """Shadow pixels of a decoded tile: dark (the studio shows dark shadow on a light backdrop)."""
    return rgb.astype(float).mean(axis=2) < 128


def iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def poses(hand, n: int) -> list[np.ndarray]:
    """n distinct poses: the wrist swinging and two fingers curling a little more each time."""
    out = []
    for i in range(n):
        q = hand.rest_pose().copy()
        q[hand.joint_names.index("wrist")] = [-0.6, 0.0, 0.6, 0.2, -0.3, 0.4][i % 6]
        for joint in ("index_mcp_flex", "middle_mcp_flex"):
            q[hand.joint_names.index(joint)] = 0.25 * (i + 1)
        out.append(q)
    return out


def horse(folder, roll: float = ROLL_DEG) -> Project:
    return Project.create(folder / "horse.shadow", sources=[asset("videos/muybridge_horse.gif")],
                          video=VideoConfig(size=64), roll=roll)  # fmt: skip


def give_results(project: Project, hand, which=None) -> None:
    rig = Rig(resolution=project.state.targets.shape[-1], roll=project.mount.roll)
    for kf, q in zip(project.keyframes, poses(hand, len(project.keyframes))):
        if which is None or kf.id in which:
            shadow = ShadowRenderer(hand, rig).render_one(q)
            project.set_result(kf.id, q, {"total": 0.1 + kf.id / 100}, shadow, inputs=project.keyframe_inputs(kf.id))


def plan(project: Project, hand) -> None:
    timing = project.show_timing()
    show = plan_show(hand, timing.keyframes, PlanConfig(timing=TimingConfig(allow_late=True))).show
    project.set_show(replace(show, roll=project.mount.roll), inputs=project.show_inputs())


@pytest.fixture(scope="module")
def planned(tmp_path_factory, hand):
    """The horse (5 frames, 5 keyframes) at 64² masks, every keyframe posed differently, its show planned
    (faster than the servos: late transitions stretched), mounted rolled by ROLL_DEG; with its rendered preview."""
    project = horse(tmp_path_factory.mktemp("preview"))
    give_results(project, hand)
    plan(project, hand)
    preview = render_preview(preview_inputs(project), PreviewConfig())
    return project, preview


def test_preview_frames_show_source_target_and_the_shows_shadow_as_mounted(planned, hand):
    project, preview = planned
    s, show = project.state, project.show
    clock = preview.clock
    assert clock.planned and len(preview.frames) == len(clock.times) == round(show.duration * 25)
    frames = [decode_image(f) for f in preview.frames]
    assert all(f.shape == (TILE, 3 * TILE + 8, 3) for f in frames)
    sources = framed_frames(s.sources, s.frames, project.path, s.video)
    rolled = ShadowRenderer(hand, Rig(resolution=64, roll=project.mount.roll))
    upright = ShadowRenderer(hand, Rig(resolution=64))
    masks = project.combined_masks()
    for m in (0, len(frames) // 2, len(frames) - 1):
        rgb, i = frames[m], int(clock.frame[m])
        # the source column is the framed source frame (below the time written on it), not the mask
        src = column(rgb, "source")[40:].astype(float)
        assert np.abs(src - fit_tile(sources[i], TILE)[40:]).mean() < 8
        assert np.abs(src - tint(s.targets[i], masks[i], TILE)[40:]).mean() > 30
        # the target column: the shape dark (expressive parts tinted), the backdrop light, never the other way
        expected = tint(s.targets[i], masks[i], TILE)
        got = column(rgb, "target")
        assert np.median(np.abs(got.astype(float) - expected).max(axis=2)) < 10
        shape = tint(s.targets[i], None, TILE)[..., 0] == 40  # the shape's pixels at the tile's size
        plain = tint(np.zeros_like(s.targets[i]), masks[i], TILE)[..., 0] == BACKDROP[0]  # not expressive
        assert got[shape].mean() < 150 < got[~shape].mean()
        assert np.abs(got[~shape & plain].astype(float) - BACKDROP).mean() < 12
        # the shadow column is the show's pose at that time, rendered with the mount roll
        t = float(clock.times[m])
        seen = dark(column(rgb, "shadow"))
        want = dark(tint(rolled.render_one(show.sample(t)), None, TILE))
        assert iou(seen, want) > 0.9 > iou(seen, dark(tint(upright.render_one(show.sample(t)), None, TILE)))
    first, last = dark(column(frames[0], "shadow")), dark(column(frames[-1], "shadow"))
    assert (first != last).sum() > 0.02 * first.size  # the shadow moves with the show …
    assert iou(first, dark(column(frames[1], "shadow"))) > 0.8  # … smoothly


def test_the_side_by_side_video_plays_the_previews_frames(planned, tmp_path):
    """One way to say what plays when: side_by_side.mp4 shows, frame by frame, the preview clock's frame (late
    transitions stretched as planned) beside the show's shadow as mounted, at the source's rate."""
    import cv2

    from studio.project.outputs import write_outputs
    from studio.review.preview import preview_shadows
    from studio.review.video_review import side_by_side_frame

    project, _ = planned
    s = project.state
    path = write_outputs(project, tmp_path / "out")["side_by_side.mp4"]
    fps = next(src.fps for src in s.sources if src.kind != "still")
    clock = preview_clock(preview_inputs(project), fps)
    cap = cv2.VideoCapture(str(path))
    rate, frames = cap.get(cv2.CAP_PROP_FPS), []
    while (got := cap.read())[0]:
        frames.append(got[1][..., ::-1])
    cap.release()
    assert len(frames) == len(clock.times) > 2 and rate == pytest.approx(fps, rel=0.05)
    sources = framed_frames(s.sources, s.frames, project.path, s.video)
    shadows = preview_shadows(clock.theta, s.targets.shape[-1], project.mount.roll)
    masks = project.combined_masks()
    for m in (0, len(frames) // 2, len(frames) - 1):
        i = int(clock.frame[m])
        want = side_by_side_frame(sources[i], s.targets[i], masks[i], shadows[m], f"{clock.times[m]:.2f}s #{i}", TILE)
        assert frames[m].shape == want.shape and np.abs(frames[m].astype(float) - want).mean() < 10


def test_timeline_marks_keyframes_and_late_transitions(planned):
    project, preview = planned
    clock = preview.clock
    assert [t.keyframe for t in clock.ticks] == [kf.id for kf in project.keyframes]
    assert all(t.status == "current" for t in clock.ticks)
    assert clock.late, "the horse is faster than the servos: its show was stretched"
    img = timeline_image(clock, 640, 24)
    for tick in clock.ticks:
        x = int(timeline_x(tick.t, clock.start, clock.end, 640))
        assert tuple(img[3, x]) == STATUS_RGB["current"]
    a, b = clock.late[0]
    mid = int(timeline_x((a + b) / 2, clock.start, clock.end, 640))
    if all(abs(mid - int(timeline_x(t.t, clock.start, clock.end, 640))) > 2 for t in clock.ticks):
        assert tuple(img[3, mid]) == LATE_RGB
    # the late transitions shift the keyframes: each tick is at its marker on the show's clock
    marks = np.array([m.t for m in project.show.keyframes])
    assert all(np.isclose(marks, t.t).any() for t in clock.ticks)
    assert clock.ticks[-1].t > project.show_timing().keyframes.times[len(clock.ticks) - 1]


def test_timeline_tick_colours_follow_each_keyframes_status(tmp_path, hand):
    project = horse(tmp_path, roll=0.0)
    ids = [kf.id for kf in project.keyframes]
    give_results(project, hand, which=ids[:2])
    q = poses(hand, 3)[2]
    project.set_result(ids[2], q, {"total": 0.3}, np.zeros((64, 64), np.uint8), inputs="inputs-since-changed")
    status = project.status()
    assert status.result_state(ids[2]) == "stale" and status.result_state(ids[3]) == "missing"
    clock = preview_clock(preview_inputs(project), 25.0)
    assert not clock.planned and "no show" not in clock.note  # keyframes to optimise first
    img = timeline_image(clock, 640, 24)
    seen = {}
    for tick in clock.ticks:
        x = int(timeline_x(tick.t, clock.start, clock.end, 640))
        seen[tick.keyframe] = tuple(int(c) for c in img[2, x])
    assert seen == {k: STATUS_RGB[status.result_state(k)] for k in ids}
    # without a show each frame plays its keyframe's pose; a keyframe with none leaves the backdrop bare
    frames = render_preview(preview_inputs(project), PreviewConfig()).frames
    missing = [m for m, i in enumerate(clock.frame) if project.assignment()[i] >= 3]
    posed = [m for m, i in enumerate(clock.frame) if project.assignment()[i] < 2]
    assert not dark(column(decode_image(frames[missing[0]]), "shadow")).any()
    assert dark(column(decode_image(frames[posed[0]]), "shadow")).sum() > 200


def test_a_cancelled_preview_returns_nothing(planned):
    cancel = threading.Event()
    cancel.set()
    assert render_preview(preview_inputs(planned[0]), PreviewConfig(), cancel=cancel) is None


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


def test_a_stills_preview_moves_from_home_and_holds_the_pose(tmp_path, hand):
    project = Project.create(tmp_path / "still.shadow", sources=[asset("targets/asl_y.jpeg")], roll=0.0)
    give_results(project, hand)
    plan(project, hand)
    pose = project.results[project.keyframes[0].id].theta(hand.joint_names)
    preview = render_preview(preview_inputs(project), PreviewConfig(home=0.5))
    clock = preview.clock
    assert clock.times[0] < 0 <= clock.times[-1] and np.allclose(clock.theta[0], hand.rest_pose())
    assert np.allclose(clock.theta[-1], pose, atol=1e-6)
    frames = [decode_image(f) for f in preview.frames]
    renderer = ShadowRenderer(hand, Rig(resolution=project.state.targets.shape[-1]))
    rest = dark(tint(renderer.render_one(hand.rest_pose()), None, TILE))
    held = dark(tint(renderer.render_one(pose), None, TILE))
    assert iou(dark(column(frames[0], "shadow")), rest) > 0.9
    hold = [m for m, t in enumerate(clock.times) if t >= 0]
    assert len(hold) == 50  # the still's 2 s hold at 25 fps
    for m in hold[:: len(hold) // 5]:
        assert iou(dark(column(frames[m], "shadow")), held) > 0.9
    assert iou(rest, held) < 0.9
    assert np.array_equal(decode_image(png(timeline_image(clock))), timeline_image(clock))


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
KERNEL_IDLE = """() => { const w = window.jupyterapp && window.jupyterapp.shell.currentWidget;
  const k = w && w.sessionContext && w.sessionContext.session && w.sessionContext.session.kernel;
  return !!k && k.connectionStatus === 'connected' && k.status === 'idle'; }"""
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
    from test_browser import CHROMIUM, CHROMIUM_FLAGS, playwright_api

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
