"""The one end-to-end browser test (DESIGN §6 "JupyterLab in headless Chromium"), checking what a person sees by its
pixels (DESIGN §5.15): ``shadow-studio lab`` serves ``studio.ipynb`` on a free local port, headless Chromium (Debian's
``chromium``, driven by Playwright) opens it, waits for the kernel and runs every cell. The project is the bundled
horse clip (its square frames padded with black bars, as the artist sees them) with a result for every keyframe and
its show planned, so the studio has a show to play. Then, tab by tab, with a screenshot of each (``tab_<name>.png``,
written as it is taken into ``$SHADOW_STUDIO_SCREENSHOT``, a folder, when set, else the test's own folder):

- every panel shows its label, none is "unavailable", none shows the browser's broken-picture icon (an empty image)
  or cuts a button's or a field's label short (an ellipsis where its words should be);
- **Keyframes**: the live count at the project's τ lands and agrees with the project's keyframes (worked out in the
  tab's own thread as the studio opens);
- **Masks**: a drag of the mouse across the frame paints: its path is drawn green in the canvas's pixels, and the
  project saves the stroke as its own PNG;
- **Targets**: the preview tints the horse, not the backdrop nor the black bars: its tinted pixels match the mask
  the project stored;
- **Review**: the embedded Rerun viewer fills the output area's width and its canvas draws the recording (the target
  image's white backdrop and black shape in the canvas's pixels, not a blank canvas or Rerun's dark welcome page);
  the show player is there and plays the planned show: its shadow column holds a dark shadow, and that shadow
  changes between two pictures taken at different show times (the time written on the source column does not
  count); while it plays, the rig scene (meshcat) follows the pose played and is never blank: every picture of it
  taken over at least 4 s shows the lit backdrop, the light and the hand's shadow, not meshcat's empty default scene,
  and the pictures change; paused, the Rerun viewer (moved onto ``show_time`` with the player) still draws the frame's
  target image, and its loss plot the total loss's line along the show;
- **Export**: the show played on the emulator; then (after the Jog tab, while the viewer plays it through) the
  Rerun viewer shows the play on ``show_time``: a servo angle's line in its plot (a colour no loss line has) and the
  show's frame in its image views;
- **Jog**: after connecting to the emulator and pressing the E-STOP, the button looks latched: its computed
  background is red, and so are most of its pixels in a screenshot;
- **Optimise**: a job started from the panel shows its progress advancing;
- no traceback in any output, no error in the page, and no request to anywhere but this machine (the studio works
  offline). Ctrl-C (SIGINT) then stops the verb and its server."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path
from urllib.parse import urlparse

import numpy as np
import pytest
from browser_page import (
    BROKEN_PICTURES,
    CHROMIUM,
    CHROMIUM_FLAGS,
    CUT_LABELS,
    KERNEL_IDLE,
    LOCAL_HOSTS,
    SHOWN_TAB,
    STUDIO,
    TAB,
    keep,
    open_tab,
    picture,
    picture_now,
    playwright_api,
    progress_widths,
    rerun_draws,
    rgb_of,
    shoot_tab,
    tracebacks,
)  # fmt: skip
from browser_pixels import drawn_recording, drawn_rig, over_the_shape, red, shadow_tile
from preview_support import dark, give_results, horse, plan

from studio.cli.lab import free_port
from studio.imitate.config import COMPONENTS
from studio.review.blueprint import FRAME_LOSS
from studio.review.series import PALETTE, series_colour

TOTAL_LINE = series_colour("loss/frame/total")  # the colour of the total loss's line in Rerun's plots
SERVO_LINE = next(c for c in PALETTE if c not in {series_colour(f"{FRAME_LOSS}/{n}") for n in COMPONENTS})
VIEWPORT = {"width": 1600, "height": 2300}  # the tester's 1,600 px wide window, tall enough for a whole tab
PANELS = ["Targets", "Keyframes", "Masks", "Weights", "Optimise", "Review", "Jog", "Rig", "Live", "Export"]
SCREENSHOTS = os.environ.get("SHADOW_STUDIO_SCREENSHOT")  # a folder that keeps the screenshots (unset: the test's own)


@pytest.fixture
def lab(tmp_path, hand):
    """``shadow-studio lab PROJECT`` on a free port, fresh Jupyter dirs → (url, process, project, start time); stopped
    with SIGINT. As root the verb passes JupyterLab ``--allow-root`` itself. PROJECT is the horse (five frames at 64²
    masks, mounted rolled) with every keyframe posed differently and its show planned, as preview_support makes it
    (a real optimisation would take minutes here; the shadows are the poses' own, rendered)."""
    playwright_api()  # skip (fail on CI) before starting anything
    project = horse(tmp_path)
    give_results(project, hand)
    plan(project, hand)
    config = tmp_path / "jupyter_config"
    (config / "labconfig").mkdir(parents=True)
    disabled = {"disabledExtensions": {"@jupyterlab/apputils-extension:announcements": True}}
    (config / "labconfig" / "page_config.json").write_text(json.dumps(disabled))
    env = os.environ | {"JUPYTER_CONFIG_DIR": str(config), "JUPYTER_RUNTIME_DIR": str(tmp_path / "runtime"),
                        "JUPYTERLAB_WORKSPACES_DIR": str(tmp_path / "workspaces"),
                        "SHADOW_STUDIO_HOME": str(tmp_path / "home")}  # fmt: skip
    cmd = [sys.executable, "-m", "studio.cli.main", "lab", str(project.path), "--port", str(free_port(18888)),
           "--no-browser", "--jupyter-arg=--LabApp.expose_app_in_browser=True"]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    url, t0 = None, time.perf_counter()
    try:
        for line in proc.stdout:  # the verb prints the URL once the server answers
            if m := re.search(r"(http://127\.0\.0\.1:\d+/lab/tree/studio\.ipynb\?token=\w+)", line):
                url = m.group(1)
                break
        assert url, f"shadow-studio lab printed no URL (exit code {proc.poll()})"
        yield url, proc, project, t0
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)  # Ctrl-C
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()


@pytest.mark.slow
def test_the_studio_in_jupyterlab(lab, tmp_path):
    sync_playwright = playwright_api()  # the fixture stopped already when it is absent
    from playwright.sync_api import Error as PlaywrightError

    url, proc, project, t0 = lab
    folder = Path(SCREENSHOTS or tmp_path)  # every screenshot is written here as it is taken
    folder.mkdir(parents=True, exist_ok=True)
    shots: list[Path] = []
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_FLAGS)
        page = browser.new_page(viewport=VIEWPORT)
        errors: list[str] = []
        outside: list[str] = []  # requests to anywhere but this machine
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.on("request", lambda r: None if urlparse(r.url).scheme not in ("http", "https", "ws", "wss")
                or urlparse(r.url).hostname in LOCAL_HOSTS else outside.append(r.url))  # fmt: skip
        page.goto(url)
        marks = {"lab up": time.perf_counter() - t0}
        page.wait_for_function(KERNEL_IDLE, timeout=90_000)
        page.evaluate("() => window.jupyterapp.commands.execute('notebook:run-all-cells')")
        page.locator(STUDIO).first.wait_for(timeout=90_000)
        page.wait_for_function(KERNEL_IDLE, timeout=90_000)
        marks["studio shown"] = time.perf_counter() - t0
        assert not tracebacks(page)

        texts = {}
        for name in PANELS:
            texts[name] = open_tab(page, name)
            assert name in texts[name], f"the {name} tab shows no {name!r} label: {texts[name][:200]!r}"
            assert "unavailable" not in texts[name], texts[name][:300]
            assert not page.evaluate(BROKEN_PICTURES), f"the {name} tab shows a broken-picture icon (an empty image)"
            cut = page.evaluate(CUT_LABELS)
            assert not cut, f"the {name} tab cuts these labels short: {cut}"
            if name in ("Keyframes", "Masks", "Weights", "Rig", "Live", "Export"):
                shots.append(shoot_tab(page, name, folder))

        # Masks: a drag of the mouse across the frame paints: the stroke is drawn (green, the legend's "painted in")
        # where the mouse went, and the project keeps it as its own PNG
        open_tab(page, "Masks")
        paint = page.locator(f"{TAB} canvas").first
        paint.scroll_into_view_if_needed()
        box = paint.bounding_box()
        x0, x1, y = box["x"] + 0.2 * box["width"], box["x"] + 0.7 * box["width"], box["y"] + 0.2 * box["height"]
        page.mouse.move(x0, y)
        page.mouse.down()
        page.mouse.move(x1, y, steps=12)
        page.mouse.up()
        deadline = time.monotonic() + 30
        while not list((project.path / "masks").glob("add-*.png")) and time.monotonic() < deadline:
            page.wait_for_timeout(250)
        assert list((project.path / "masks").glob("add-*.png")), "a stroke painted with the mouse was not saved"
        painted = picture(paint)
        keep(painted, folder / "masks_painted.png")
        h, w = painted.shape[:2]
        g = painted.astype(int)
        green = (g[..., 1] - g[..., 0] > 60) & (g[..., 1] - g[..., 2] > 40)
        row = green[int(0.2 * h) - 3 : int(0.2 * h) + 4]
        along = row[:, int(0.25 * w) : int(0.65 * w)].any(axis=0).mean()
        assert along > 0.9 and not green[int(0.5 * h) :].any(), (
            f"the stroke is not drawn where the mouse went: {along:.0%} of its path green, {green.mean():.1%} painted"
        )
        page.locator(f"{TAB} button", has_text="Undo").first.click()  # the keyframe's result is current again
        page.locator(f"{TAB} .widget-label:text-is('frame 0')").first.wait_for(timeout=30_000)

        # Keyframes: the count at the project's τ lands (the tab works it out in its own thread as the studio opens)
        open_tab(page, "Keyframes")
        tau, n = project.state.clustering.tau, len(project.keyframes)
        page.locator(f"{TAB} .widget-label:has-text('at τ {tau:.3f} (project: {n})')").first.wait_for(timeout=30_000)

        # Targets: the preview tints the shape the project stored, not the backdrop nor the black bars around it
        open_tab(page, "Targets")
        preview = page.locator(f"{TAB} .widget-vbox:has(> .widget-html:has-text('threshold alone')) > img").first
        preview.scroll_into_view_if_needed()
        shown = picture(preview)
        keep(shown, folder / "targets_preview.png")
        on_shape, off_shape = over_the_shape(shown, project.state.targets[0])
        assert on_shape > 0.85 and off_shape < 0.15, (
            f"the Targets preview does not tint the stored shape: {on_shape:.0%} of its pixels tinted, {off_shape:.0%} "
            "of the backdrop and the black bars"
        )
        shots.append(shoot_tab(page, "Targets", folder))

        # Review: the Rerun viewer, as wide as the output area, draws the recording; the show player plays
        open_tab(page, "Review")
        canvas = page.locator(f"{TAB} .rerun_notebook canvas").first
        canvas.wait_for(timeout=60_000)
        canvas.scroll_into_view_if_needed()
        area = page.locator(STUDIO).first.bounding_box()
        box = canvas.bounding_box()
        assert box["width"] >= 0.9 * area["width"] and box["height"] >= 400, (box, area)
        facts: dict = {}
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            drawn = picture(canvas)
            keep(drawn, folder / "rerun_canvas.png")
            ok, facts = drawn_recording(drawn)
            if ok:
                break
            page.wait_for_timeout(1000)
        if not ok:
            shoot_tab(page, "Review", folder)
        assert ok, f"the Rerun viewer does not draw the recording (blank or its welcome page): {facts}"
        marks["rerun drawn"] = time.perf_counter() - t0
        # the show player (widgets.show_player) plays the planned show: a dark shadow that moves with the show time
        player = page.locator(f"{TAB} .show-player")
        player.first.wait_for(timeout=30_000)
        assert player.count() == 1, "the Review tab has no show player"
        scrub = "document.querySelector(\"[data-shown-tab='1'] .show-player input[type=range]\")"
        page.wait_for_function(f"() => Number(({scrub} || {{}}).max) > 0", timeout=90_000)  # it has frames
        marks["preview ready"] = time.perf_counter() - t0
        assert "the planned show" in page.evaluate(SHOWN_TAB), "the player shows no planned show"
        screen = player.locator("canvas").first
        screen.scroll_into_view_if_needed()  # while it holds still
        player.locator("input[type=checkbox]").first.check()  # loop
        player.locator("button", has_text="Play").first.click()
        played = []  # (the preview frame in view, its shadow tile's dark pixels) while it plays
        moved = False
        for _ in range(10):  # the time written on the source column does not count: only the shadow tile is compared
            shown_at = player.get_attribute("data-frame")
            frame = picture_now(page, screen)
            played.append((shown_at, dark(shadow_tile(frame))))
            keep(frame, folder / ("player_first.png" if len(played) == 1 else "player_later.png"))
            (at_first, first), (at_now, now) = played[0], played[-1]
            moved = at_now != at_first and (first != now).mean() > 0.01
            if moved:
                break
            page.wait_for_timeout(300)
        shares = [round(float(d.mean()), 3) for _, d in played]
        assert all(0.01 < share < 0.7 for share in shares), f"the show player's shadow column is blank: {shares}"
        assert moved, f"the shadow in the show player does not change while it plays (dark shares {shares})"
        # while it plays the rig scene follows the pose played, snapshot after snapshot: never a blank moment
        stack = page.locator(f"{TAB} .scene-snapshot").last  # holds the snapshots (widgets.scene_snapshot)
        stack.scroll_into_view_if_needed()
        box, during, changed = stack.bounding_box(), [], [0.0]

        def moved_share(a: np.ndarray, b: np.ndarray) -> float:  # identical snapshots differ by no pixel at all
            return float((np.abs(b.astype(int) - a.astype(int)).max(axis=-1) > 30).mean())

        start = time.monotonic()  # the scene is redrawn every follow_interval_s (0.5 s) while the show plays
        while time.monotonic() - start < 4.0 or (max(changed) < 1e-4 and time.monotonic() - start < 15.0):
            during.append(rgb_of(page.screenshot(clip=box)))
            if len(during) > 1:
                changed.append(moved_share(during[-2], during[-1]))
        blank = [i for i, shot in enumerate(during) if not drawn_rig(shot)[0]]
        if blank:
            keep(during[blank[0]], folder / "rig_scene_blank.png")
        assert not blank, f"the rig scene went blank while the show played: {len(blank)} of {len(during)} pictures"
        assert max(changed) > 1e-4, f"the rig scene does not follow the show as it plays: {changed}"
        player.locator("button", has_text="Pause").first.dispatch_event("click")  # it moves while it plays
        marks["player plays"] = time.perf_counter() - t0
        # the rig in meshcat (the Review tab's scene): the hand, its light and its shadow on the backdrop, drawn
        scene = page.locator(f"{TAB} .scene-snapshot").last
        drawn, rig_facts, rig = False, {}, None
        for _ in range(30):  # the panel replaces the snapshot when the pose shown changes (the pause): a new one
            try:
                scene.scroll_into_view_if_needed(timeout=2000)
                rig = picture(scene)
            except PlaywrightError as e:  # replaced while it was being looked at
                rig_facts = {"replaced": str(e).splitlines()[0]}
            else:
                drawn, rig_facts = drawn_rig(rig)
                if drawn:
                    break
            page.wait_for_timeout(500)
        if rig is not None:
            keep(rig, folder / "rig_scene.png")
        assert drawn, f"the Review tab's meshcat scene does not draw the rig: {rig_facts}"
        # the Rerun viewer followed the player onto show_time: its views show the frame played there, not "No data",
        # and its loss plot the frames' losses along the show (the total's line, in its colour)
        (ok, facts), (line, line_facts) = rerun_draws(page, canvas, TOTAL_LINE, folder / "rerun_on_show_time.png")
        assert ok, f"the Rerun viewer shows no frame at the show time the player stopped at: {facts}"
        assert line, f"the Rerun viewer's loss plot draws no loss along the show: {line_facts}"
        shots.append(shoot_tab(page, "Review", folder))

        # Export: play the show on the emulator; the Rerun viewer then plays it on show_time with the servo plot in
        # front (a line of a colour no loss series has: one of the played joints') and the show's frames beside it
        open_tab(page, "Export")
        page.locator(f"{TAB} button", has_text="play").first.click()
        page.locator(f"{TAB} .widget-html:has-text('played '), {TAB} .widget-label:has-text('played ')").first.wait_for(
            timeout=60_000
        )
        marks["played"] = time.perf_counter() - t0

        # Jog: connect to the emulator, press the e-stop, see it latched: the button turns red (its style, and the
        # pixels a person sees) and says so
        open_tab(page, "Jog")
        page.locator(f"{TAB} button", has_text="connect").first.click()
        estop = page.locator(f"{TAB} button", has_text="E-STOP").first
        page.wait_for_function(
            "() => !document.evaluate(\"//button[contains(., 'E-STOP')]\", document).iterateNext().disabled",
            timeout=30_000,
        )
        estop.click()
        page.locator(f"{TAB} button", has_text="LATCHED").first.wait_for(timeout=15_000)
        colour = estop.evaluate("b => getComputedStyle(b).backgroundColor")
        r, g, b = (int(v) for v in re.findall(r"\d+", colour)[:3])
        assert r >= 100 and r > 2 * g and r > 2 * b, f"the latched E-STOP is not red: {colour}"
        button = picture(estop)
        keep(button, folder / "estop_latched.png")
        assert red(button).mean() > 0.5, f"the latched E-STOP does not look red: {red(button).mean():.0%} red pixels"
        shots.append(shoot_tab(page, "Jog", folder))

        # back to Review: the play ended while the Jog tab was tried (the viewer has played it through by now)
        open_tab(page, "Review")
        (ok, facts), (line, line_facts) = rerun_draws(page, canvas, SERVO_LINE, folder / "rerun_after_play.png")
        assert line, f"after a play the Rerun viewer shows no servo angles (its plot tab): {line_facts}"
        # the angles from the ramp's start on: no legend of 42 series over the plot's left third (9 columns there)
        assert line_facts["left_columns"] >= 40, f"the servo plot's left third is covered: {line_facts}"
        assert ok, f"after a play the Rerun viewer's image views show no frame of the show: {facts}"
        marks["play reviewed"] = time.perf_counter() - t0

        # Optimise: start this keyframe and see a progress bar advance
        open_tab(page, "Optimise")
        page.locator(f"{TAB} button", has_text="This keyframe").first.click()
        seen: list[tuple[float, ...]] = []  # the widths of the job's bars (retrieve, search, refine) over time

        def advanced() -> bool:  # some bar was drawn at two different non-zero widths
            return any(len({t[i] for t in seen if len(t) > i and t[i] > 0}) >= 2 for i in range(3))

        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            widths = progress_widths(page)
            if widths:
                seen.append(tuple(widths))
            if advanced():
                break
            page.wait_for_timeout(250)
        assert advanced(), f"no progress seen advancing: {seen}"
        marks["progress seen"] = time.perf_counter() - t0
        shots.append(shoot_tab(page, "Optimise", folder))
        cancel = page.locator(f"{TAB} button", has_text="Cancel").first
        if cancel.is_enabled():  # spare the CPU for the rest (the panel's own tests check cancelling)
            cancel.click()

        found = tracebacks(page)
        browser.close()
    seconds = time.perf_counter() - t0
    assert not found, found
    # anywidget rejects a model's start after a fixed 2 s (its Runtime's AbortSignal.timeout(2000)) even when the
    # model then starts: on two loaded cores the Rerun viewer's 23 MB module can take longer. Every widget was
    # checked above by its pixels, which is what fails when one really does not start.
    slow_start = "[anywidget] Failed to initialize model."
    assert not [e for e in errors if e != slow_start], errors
    assert not outside, f"the studio reached outside this machine: {outside}"
    assert sorted(s.name for s in shots) == sorted(f"tab_{name.lower()}.png" for name in PANELS)  # one a tab
    assert all(s.stat().st_size > 10_000 for s in shots)
    print(f"browser part took {seconds:.1f} s:", {k: round(v, 1) for k, v in marks.items()}, "Rerun canvas:", facts)
    proc.send_signal(signal.SIGINT)  # Ctrl-C stops the verb and its server
    assert proc.wait(30) == 0
