"""What Rerun's own web viewer draws of a review's series, in a real headless Chromium (pixels of the plot): a frame's
loss logged again after an edit shows the new value only, never the average of the two versions that Rerun draws for
rows sharing a time; the keyframe each frame plays is a dot per frame, not a line between keyframes."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from browser_page import CHROMIUM, CHROMIUM_FLAGS, playwright_api
from test_review_series import edited

from studio.cli.lab import free_port
from studio.review.frames import KeyframeReview
from studio.review.series import PALETTE, VersionedLog, series_colour


def stop_group(proc: subprocess.Popen) -> None:
    """End ``proc`` and every process it started (its own session's group): SIGTERM, then SIGKILL after 10 s."""
    for sig in (signal.SIGTERM, signal.SIGKILL):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        try:
            proc.wait(10)
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)  # a child that outlived its parent
            return
        except subprocess.TimeoutExpired:
            continue


def near(rgb: np.ndarray, colour: tuple[int, int, int], tolerance: int = 40) -> np.ndarray:
    """Pixels of ``rgb (H, W, 3)`` within ``tolerance`` of ``colour`` in every channel: ``(H, W)`` bool."""
    return (np.abs(rgb.astype(int) - np.array(colour)) <= tolerance).all(axis=-1)


def viewer_screenshot(path: Path, done, seconds: float = 90) -> np.ndarray | None:
    """Serve the recording at ``path`` with Rerun's web viewer and screenshot it in headless Chromium (800 × 520)
    until ``done(rgb)`` (a viewer still loading draws less), or ``seconds`` pass; the last screenshot (RGB), None
    when the viewer never answered."""
    sync_playwright = playwright_api()
    import cv2

    web, grpc = free_port(19090), free_port(19877)
    cmd = [sys.executable, "-m", "rerun", "--serve-web", "--bind", "127.0.0.1", "--web-viewer-port", str(web),
           "--port", str(grpc), str(path)]  # fmt: skip
    # its own process group: `python -m rerun` runs the rerun binary as a child, which a plain terminate leaves behind
    server = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    rgb = None
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_FLAGS)
            page = browser.new_page(viewport={"width": 800, "height": 520})
            url = f"http://127.0.0.1:{web}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc}%2Fproxy"
            deadline, opened = time.monotonic() + seconds, False
            while time.monotonic() < deadline:
                try:
                    if not opened:
                        page.goto(url)
                        opened = True
                    page.wait_for_timeout(700)
                    png = page.screenshot()
                except Exception:  # the server is still starting
                    opened = False
                    page.wait_for_timeout(500)
                    continue
                rgb = cv2.cvtColor(cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
                if done(rgb):
                    break
            browser.close()
    finally:
        stop_group(server)
    if rgb is not None:
        cv2.imwrite(str(path.with_suffix(".png")), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return rgb


@pytest.mark.slow
def test_rerun_draws_the_new_losses_not_the_average_of_both_versions(tmp_path):
    path = tmp_path / "r.rrd"
    edited(path)
    total, base = series_colour("loss/frame/total"), series_colour("loss/frame/base")
    assert total == PALETTE[0] and base == PALETTE[1]  # blue and orange: apart from everything else drawn

    def total_reach(rgb: np.ndarray) -> tuple[float | None, dict]:
        """How far the total's line reaches along the base's (which spans every frame: the plot's width), in the
        layout's left column (the plots); None while either line is not drawn."""
        left = rgb[:, : int(rgb.shape[1] * 0.6)]
        _, bx = np.nonzero(near(left, total))
        _, ox = np.nonzero(near(left, base))
        facts = {"total_px": int(len(bx)), "base_px": int(len(ox))}
        if len(ox) <= 100 or len(bx) <= 30:
            return None, facts
        x0, x1 = np.percentile(ox, 2), np.percentile(ox, 98)
        return float((np.percentile(bx, 98) - x0) / (x1 - x0)), facts

    # total is drawn over frames 0-4 only (4/9 of the width), at 0.8; averaged with the old version it would reach
    # the last frame (at 0.5 over frames 0-4, 0.2 after). Polled until so (a viewer still loading draws less).
    rgb = viewer_screenshot(path, lambda rgb: (lambda r: r is not None and 0.3 < r < 0.6)(total_reach(rgb)[0]))
    assert rgb is not None, "the web viewer never answered"
    reach, facts = total_reach(rgb)
    where = path.with_suffix(".png")
    assert reach is not None, f"the loss plot draws no base or total line: {facts} ({where})"
    assert 0.3 < reach < 0.6, f"total reaches {reach:.2f} of the plot's width ({where})"


@pytest.mark.slow
def test_rerun_draws_the_keyframe_of_each_frame_as_a_dot_per_frame(tmp_path):
    import rerun.blueprint as rrb

    from studio.review.blueprint import KEYFRAME_OF_FRAME
    from studio.review.frames import log_frame_series

    path = tmp_path / "k.rrd"
    rec = rr.RecordingStream("shadow-studio-test")
    view = rrb.Blueprint(rrb.TimeSeriesView(origin=KEYFRAME_OF_FRAME), collapse_panels=True)  # the plot alone
    rec.save(str(path), default_blueprint=view)
    which = np.array([0, 0, 0, 1, 1, 1, 1, 2, 2, 2])  # keyframe 1 (frames 3-6) in the middle of the plot's range
    three = [KeyframeReview(k, int(np.flatnonzero(which == k)[0]), tuple(np.flatnonzero(which == k))) for k in range(3)]
    log_frame_series(VersionedLog(rec), three, which)
    rec.flush()
    rec.disconnect()
    colour = series_colour(KEYFRAME_OF_FRAME)

    def drawn(rgb: np.ndarray) -> tuple[int, float]:
        """In the band across the middle of the plot, where keyframe 1 is drawn: the runs of pixel columns holding
        the series' colour, and the share of the columns between the first and the last that hold it. Dots give a
        run a frame and a small share; a line crosses the band from keyframe 0's level to 2's: one run, most of it."""
        h = rgb.shape[0]
        _, xs = np.nonzero(near(rgb[int(0.4 * h) : int(0.6 * h)], colour))
        xs = np.unique(xs)
        if len(xs) == 0:
            return 0, 0.0
        return 1 + int((np.diff(xs) > 3).sum()), len(xs) / (xs[-1] - xs[0] + 1)

    rgb = viewer_screenshot(path, lambda rgb: drawn(rgb)[0] >= 4)
    assert rgb is not None, "the web viewer never answered"
    runs, share = drawn(rgb)
    where = path.with_suffix(".png")
    assert runs >= 4 and share < 0.5, f"{runs} marks, {share:.0%} covered for frames 3-6: a line, not dots ({where})"
