"""The Rerun viewer widget for notebooks (studio.review.notebook_viewer), offline: the frontend first sees the widget
with its url and size (updates sent after it is made can be lost while its ~23 MB module loads: a 200 px box on
Rerun's welcome page), its module refuses to fetch from the internet, and importing it prints nothing."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess

import ipywidgets as w
import pytest

from studio.review.notebook_viewer import MIN_HEIGHT, OFFLINE_GUARD, clamp_height, notebook_viewer, viewer_class

pytestmark = pytest.mark.skipif(importlib.util.find_spec("rerun_notebook") is None,
                                reason="the notebook viewer needs the rerun-notebook package")  # fmt: skip

URL = "rerun+http://127.0.0.1:9/proxy"


def test_the_frontend_first_sees_the_url_and_the_size(monkeypatch):
    opened: dict[str, dict] = {}
    real_open = w.Widget.open

    def spy(self) -> None:  # the state the widget's model is created with in the browser
        opened.setdefault(type(self).__name__, {k: v for k, v in self.get_state().items() if k != "_esm"})
        real_open(self)

    monkeypatch.setattr(w.Widget, "open", spy)
    viewer = notebook_viewer(URL, height=500, panels={"blueprint": "collapsed"})
    first = opened["StudioRerunViewer"]
    assert (first["_url"], first["_width"], first["_height"]) == (URL, "auto", 500)  # 100 % wide, 500 px
    assert first["_panel_states"] == {"blueprint": "collapsed"}
    assert (viewer._url, viewer._width, viewer._height) == (URL, "auto", 500)
    viewer._height = 720  # what the panel's height control does: the frontend resizes on this change
    assert viewer.get_state()["_height"] == 720


def test_the_module_carries_the_offline_guard_and_import_prints_nothing(capfd):
    assert os.environ["RERUN_NOTEBOOK_ASSET"] == "inline"  # set by studio.review before rerun_notebook loads
    cls = viewer_class()
    assert cls is viewer_class()  # made once
    esm = str(cls._esm)
    assert esm.startswith(OFFLINE_GUARD) and len(esm) > 10_000_000  # the guard, then the whole viewer inline
    assert "const fetch = " in OFFLINE_GUARD and "/^127\\./" in OFFLINE_GUARD and "status: 503" in OFFLINE_GUARD
    assert "api.github.com" not in OFFLINE_GUARD  # nothing named: every outside address is refused
    notebook_viewer(URL)
    assert capfd.readouterr().out == ""  # rerun_notebook's "Loading inline widget ..." is not shown


def test_heights_are_clamped():
    assert clamp_height(10) == MIN_HEIGHT and clamp_height(600) == 600 and clamp_height(10**6) == 2000


@pytest.mark.skipif(shutil.which("node") is None, reason="running the guard needs node")
def test_the_guard_lets_only_local_fetches_through(tmp_path):
    """The guard run as the viewer's module runs it: the page's and the loopback's addresses reach the page's fetch;
    GitHub (the version check) and any other outside address are answered 503 without a request."""
    script = tmp_path / "guard.mjs"
    script.write_text(
        'globalThis.location = { href: "http://127.0.0.1:8888/lab/x", origin: "http://127.0.0.1:8888" };\n'
        "const asked = [];\n"
        'globalThis.fetch = async (input) => { asked.push(String(input)); return new Response("ok"); };\n'
        + OFFLINE_GUARD
        + "const urls = ['https://api.github.com/repos/rerun-io/rerun/releases/latest', 'https://app.rerun.io/x',\n"
        "  'http://127.0.0.1:50743/rerun.sdk_comms.v1alpha1.MessageProxyService/ReadMessages', '/lab/api/x',\n"
        "  'http://localhost:9/y', 'data:application/octet-stream;base64,AA==', 'http://10.0.0.2:80/z'];\n"
        "const status = [];\n"
        "for (const u of urls) status.push((await fetch(u)).status);\n"
        "console.log(JSON.stringify({ asked, status }));\n"
    )
    out = subprocess.run(["node", str(script)], capture_output=True, text=True, timeout=60, check=True).stdout
    got = json.loads(out.strip().splitlines()[-1])
    assert got["status"] == [503, 503, 200, 200, 200, 200, 503]
    assert got["asked"] == [
        "http://127.0.0.1:50743/rerun.sdk_comms.v1alpha1.MessageProxyService/ReadMessages",
        "/lab/api/x",
        "http://localhost:9/y",
        "data:application/octet-stream;base64,AA==",
    ]


def test_silencing_the_viewer_s_import_in_a_thread_keeps_the_other_threads_output():
    """The Review panel makes its viewer in a background thread: rerun_notebook's import line is dropped there, while
    what the notebook's own thread writes meanwhile still reaches the output (a plain redirect swallowed it)."""
    import io
    import sys
    import threading

    from studio.review.notebook_viewer import _quiet

    out, inside, done = io.StringIO(), threading.Event(), threading.Event()

    def importing() -> None:
        with _quiet():
            print("Loading inline widget")
            inside.set()
            done.wait(10)

    real, sys.stdout = sys.stdout, out
    try:
        thread = threading.Thread(target=importing)
        thread.start()
        assert inside.wait(10)
        print("the notebook's own line")
        done.set()
        thread.join(10)
    finally:
        sys.stdout = real
    assert out.getvalue() == "the notebook's own line\n"
