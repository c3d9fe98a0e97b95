"""The studio's page in headless Chromium, for the browser tests (tests/test_browser.py, and the Rerun and player
tests that open their own JupyterLab): where Chromium is, the selectors and page scripts that find the studio and
its tab on show, and the helpers that open a tab, take a picture of an element and wait for the Rerun viewer."""

from __future__ import annotations

import os
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
from browser_pixels import drawn_recording, plotted

CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_FLAGS = ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--disable-background-networking",
                  "--disable-component-update", "--disable-sync", "--no-first-run"]  # fmt: skip
STUDIO = ".jp-OutputArea-output .shadow-studio"
LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1", "[::1]")

KERNEL_IDLE = """() => {
  const w = window.jupyterapp && window.jupyterapp.shell.currentWidget;
  const k = w && w.sessionContext && w.sessionContext.session && w.sessionContext.session.kernel;
  return !!k && k.connectionStatus === 'connected' && k.status === 'idle';
}"""
BROKEN_PICTURES = """() => Array.from(document.querySelectorAll(
  ".jp-OutputArea-output .shadow-studio [data-shown-tab='1'] img"))
  .filter(i => i.offsetParent !== null && i.complete && i.naturalWidth === 0).length"""  # drawn as the broken icon
CUT_LABELS = """() => Array.from(document.querySelectorAll(
  ".jp-OutputArea-output .shadow-studio [data-shown-tab='1'] :is(button, .widget-label)"))
  .filter(b => b.offsetParent !== null && b.scrollWidth > b.clientWidth + 1).map(b => b.textContent.trim())"""
SHOWN_TAB = """() => {  // the studio tab on show (ipywidgets 8 hides the others with lm-mod-hidden)
  const tab = document.querySelector('.jp-OutputArea-output .shadow-studio .jupyter-widget-tab, '
                                     + '.jp-OutputArea-output .shadow-studio .widget-tab');
  const kids = Array.from(tab.querySelectorAll(':scope > .widget-tab-contents > *, :scope > .lm-StackedPanel > *'));
  const shown = kids.filter(k => !k.classList.contains('lm-mod-hidden') && k.offsetParent !== null);
  shown.forEach(k => k.setAttribute('data-shown-tab', '1'));
  kids.filter(k => !shown.includes(k)).forEach(k => k.removeAttribute('data-shown-tab'));
  return shown.map(k => k.innerText).join('\\n');
}"""
TAB = f"{STUDIO} [data-shown-tab='1']"  # the tab on show, once SHOWN_TAB marked it


def playwright_api():
    """Playwright's sync API, with Debian's Chromium to drive. Without either, a machine run by hand skips the browser
    tests (saying what to install); on CI (``CI`` set), where ``.ci/run`` installs both, they fail instead, so that
    the browser tests never vanish from a run that judges a change."""
    missing = pytest.fail if os.environ.get("CI") else pytest.skip
    if not CHROMIUM.is_file():
        missing(f"no chromium at {CHROMIUM} (Debian's chromium package; .ci/run installs it)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        missing("playwright is not installed (pip install -e '.[dev]')")
    return sync_playwright


def open_tab(page, name: str) -> str:
    """Show the studio tab ``name`` → its text (and mark it: :data:`TAB`)."""
    page.locator(f"{STUDIO} .lm-TabBar-tab", has_text=name).first.click()
    page.wait_for_function(
        """(name) => {
          const t = document.querySelector('.jp-OutputArea-output .shadow-studio .lm-TabBar-tab.lm-mod-current');
          return t && t.innerText.trim() === name; }""",
        arg=name,
    )
    return page.evaluate(SHOWN_TAB)


def rgb_of(png: bytes) -> np.ndarray:
    """A PNG screenshot as ``(H, W, 3)`` uint8 RGB."""
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def picture(locator) -> np.ndarray:
    """A screenshot of one element as ``(H, W, 3)`` uint8 RGB."""
    return rgb_of(locator.screenshot())


def picture_now(page, locator) -> np.ndarray:
    """What the page shows where ``locator`` is now, as ``(H, W, 3)`` uint8 RGB, without waiting for the element to
    hold still (a playing show player redraws, and its box moves with its label, several times a second)."""
    return rgb_of(page.screenshot(clip=locator.bounding_box()))


def keep(rgb: np.ndarray, path: Path) -> None:
    """Write ``rgb (H, W, 3)`` uint8 to ``path`` (PNG) for a person to look at."""
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))


def shoot_tab(page, name: str, folder: Path) -> Path:
    """The studio (tab ``name`` on show) as a person sees it → ``folder/tab_<name>.png``."""
    path = folder / f"tab_{name.lower()}.png"
    studio = page.locator(STUDIO).first
    studio.scroll_into_view_if_needed()
    studio.screenshot(path=str(path))
    return path


def progress_widths(page) -> list[float]:
    """Widths (%) of the progress bars in the tab on show."""
    return page.evaluate("""() => Array.from(document.querySelectorAll(
        ".jp-OutputArea-output .shadow-studio [data-shown-tab='1'] .progress-bar"))
        .map(b => parseFloat(b.style.width) || 0)""")


def rerun_draws(page, canvas, colour: tuple[int, int, int], path: Path, seconds: float = 30) -> tuple:
    """Look at the Rerun canvas until it draws a frame of the recording and a plot line of ``colour``, or ``seconds``
    pass; the last picture is kept at ``path`` → (drawn_recording's answer, plotted's answer)."""
    canvas.scroll_into_view_if_needed()
    deadline = time.monotonic() + seconds
    while True:
        shown = picture(canvas)
        drawn, line = drawn_recording(shown), plotted(shown, colour)
        if (drawn[0] and line[0]) or time.monotonic() > deadline:
            keep(shown, path)
            return drawn, line
        page.wait_for_timeout(1000)


def tracebacks(page) -> list[str]:
    """The text of every output that shows a traceback (the kernel's, or a panel's logged exception)."""
    return page.evaluate("""() => Array.from(document.querySelectorAll('.jp-OutputArea-output'))
        .map(e => e.innerText).filter(t => t.includes('Traceback (most recent call last)'))""")
