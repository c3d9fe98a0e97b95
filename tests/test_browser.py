"""The one end-to-end browser test (DESIGN §6 "JupyterLab in headless Chromium"): ``shadow-studio lab`` serves
``studio.ipynb`` on a free local port, headless Chromium (Debian's ``chromium``, driven by Playwright) opens it, waits
for the kernel, runs every cell, finds each panel's label in the output area, starts an optimisation from the
Optimise panel and sees its progress advance, connects the Jog panel to the emulator and presses the e-stop; a
screenshot is saved in the test's folder. Ctrl-C (SIGINT) then stops the verb and its server."""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from studio.assets import asset

from studio.cli.lab import free_port
from studio.project.project import Project

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run"]  # fmt: skip
PANELS = ["Targets", "Keyframes", "Masks", "Weights", "Optimise", "Review", "Jog", "Export"]
SCREENSHOT_COPY = os.environ.get("SHADOW_STUDIO_SCREENSHOT")  # also copy the screenshot here when set

KERNEL_IDLE = """() => {
  const w = window.jupyterapp && window.jupyterapp.shell.currentWidget;
  const k = w && w.sessionContext && w.sessionContext.session && w.sessionContext.session.kernel;
  return !!k && k.connectionStatus === 'connected' && k.status === 'idle';
}"""


def playwright_api():
    if not CHROMIUM.is_file():
        pytest.skip(f"no chromium at {CHROMIUM} (Debian's chromium package; .ci/run installs it)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (pip install -e '.[dev]')")
    return sync_playwright


@pytest.fixture
def lab(tmp_path):
    """``shadow-studio lab PROJECT`` on a free port, fresh Jupyter dirs → (url, process, start time); stopped with
    SIGINT."""
    playwright_api()  # skip before starting anything
    project = Project.create(tmp_path / "browser.shadow", sources=[asset("targets/asl_o.jpeg")])
    config = tmp_path / "jupyter_config"
    (config / "labconfig").mkdir(parents=True)
    disabled = {"disabledExtensions": {"@jupyterlab/apputils-extension:announcements": True}}
    (config / "labconfig" / "page_config.json").write_text(json.dumps(disabled))
    env = os.environ | {"JUPYTER_CONFIG_DIR": str(config), "JUPYTER_RUNTIME_DIR": str(tmp_path / "runtime"),
                        "JUPYTERLAB_WORKSPACES_DIR": str(tmp_path / "workspaces"),
                        "SHADOW_STUDIO_HOME": str(tmp_path / "home")}  # fmt: skip
    lab_args = ["--jupyter-arg=--allow-root", "--jupyter-arg=--LabApp.expose_app_in_browser=True"]
    cmd = [sys.executable, "-m", "studio.cli.main", "lab", str(project.path), "--port", str(free_port(18888)),
           "--no-browser", *lab_args]  # fmt: skip
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    url, t0 = None, time.perf_counter()
    try:
        for line in proc.stdout:  # the verb prints the URL once the server answers
            if m := re.search(r"(http://127\.0\.0\.1:\d+/lab/tree/studio\.ipynb\?token=\w+)", line):
                url = m.group(1)
                break
        assert url, f"shadow-studio lab printed no URL (exit code {proc.poll()})"
        yield url, proc, t0
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)  # Ctrl-C
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()


def visible_tab_text(page) -> str:
    """The text of the studio tab on show (ipywidgets 8 hides the others with lm-mod-hidden)."""
    return page.evaluate("""() => {
      const tab = document.querySelector('.jp-OutputArea-output .shadow-studio .jupyter-widget-tab, '
                                         + '.jp-OutputArea-output .shadow-studio .widget-tab');
      const kids = Array.from(tab.querySelectorAll(':scope > .widget-tab-contents > *, :scope > .lm-StackedPanel > *'));
      const shown = kids.filter(k => !k.classList.contains('lm-mod-hidden') && k.offsetParent !== null);
      return shown.map(k => k.innerText).join('\\n');
    }""")


def open_tab(page, name: str) -> str:
    page.locator(".jp-OutputArea-output .shadow-studio .lm-TabBar-tab", has_text=name).first.click()
    page.wait_for_function(
        """(name) => {
          const t = document.querySelector('.jp-OutputArea-output .shadow-studio .lm-TabBar-tab.lm-mod-current');
          return t && t.innerText.trim() === name; }""",
        arg=name,
    )
    return visible_tab_text(page)


def progress_widths(page) -> list[float]:
    return page.evaluate("""() => Array.from(document.querySelectorAll(
        '.jp-OutputArea-output .shadow-studio .progress-bar')).map(b => parseFloat(b.style.width) || 0)""")


@pytest.mark.slow
def test_the_studio_in_jupyterlab(lab, tmp_path):
    sync_playwright = playwright_api()  # the fixture skipped already when it is absent
    url, proc, t0 = lab
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_FLAGS)
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.goto(url)
        marks = {"lab up": time.perf_counter() - t0}
        page.wait_for_function(KERNEL_IDLE, timeout=90_000)
        page.evaluate("() => window.jupyterapp.commands.execute('notebook:run-all-cells')")
        page.locator(".jp-OutputArea-output .shadow-studio").first.wait_for(timeout=90_000)
        page.wait_for_function(KERNEL_IDLE, timeout=90_000)
        marks["studio shown"] = time.perf_counter() - t0
        assert not page.locator(".jp-OutputArea-output[data-mime-type='application/vnd.jupyter.stderr']").count()
        assert not page.locator(".jp-OutputArea-output .ansi-red-fg").count()  # no traceback anywhere
        texts = {name: open_tab(page, name) for name in PANELS}
        for name, text in texts.items():
            assert name in text, f"the {name} tab shows no {name!r} label: {text[:200]!r}"
            assert "unavailable" not in text, text[:300]
        # Optimise: start this keyframe and see a progress bar advance
        open_tab(page, "Optimise")
        page.locator(".jp-OutputArea-output .shadow-studio button", has_text="This keyframe").first.click()
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
        page.screenshot(path=str(tmp_path / "studio.png"), full_page=False)
        cancel = page.locator(".jp-OutputArea-output .shadow-studio button", has_text="Cancel").first
        if cancel.is_enabled():  # spare the CPU for the rest (the panel's own tests check cancelling)
            cancel.click()
        # Jog: connect to the emulator, press the e-stop, see it latched
        open_tab(page, "Jog")
        page.locator(".jp-OutputArea-output .shadow-studio button", has_text="connect").first.click()
        page.wait_for_function(
            "() => !document.evaluate(\"//button[contains(., 'E-STOP')]\", document).iterateNext().disabled",
            timeout=30_000,
        )
        page.locator(".jp-OutputArea-output .shadow-studio button", has_text="E-STOP").first.click()
        page.locator(".jp-OutputArea-output .shadow-studio", has_text="latched").first.wait_for(timeout=15_000)
        browser.close()
    seconds = time.perf_counter() - t0
    assert (tmp_path / "studio.png").stat().st_size > 10_000
    if SCREENSHOT_COPY:
        shutil.copyfile(tmp_path / "studio.png", SCREENSHOT_COPY)
    assert not [e for e in errors if "Failed to fetch" not in e], errors
    print(f"browser part took {seconds:.1f} s:", {k: round(v, 1) for k, v in marks.items()})
    proc.send_signal(signal.SIGINT)  # Ctrl-C stops the verb and its server
    assert proc.wait(30) == 0
