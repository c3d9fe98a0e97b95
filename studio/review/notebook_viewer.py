"""The Rerun viewer in a notebook: offline, as wide as the output area, on one recording's live gRPC stream.

    viewer = notebook_viewer(recording.server_url, height=560)   # a widget: place it in any ipywidgets layout
    viewer._height = 720                                           # resize it (the Review panel has a control)
    viewer.set_time_ctrl("frame", sequence=3, play=False)          # rerun_notebook's own call: show frame 3

Three things ``rerun.notebook.Viewer`` (rerun 0.41) gets wrong here, each seen in JupyterLab in a real browser:

- **Size and address lost.** It makes the ``rerun_notebook.Viewer`` widget first and sets its url, width and height
  afterwards, as updates. That widget's frontend module is the whole viewer inlined (~23 MB of JavaScript and
  WebAssembly), and updates that reach the page while the module is still loading are lost: the viewer came up with
  its traits' defaults, width and height 0 (drawn as a 200 × 200 px box, the toolbar cut off) and no url, so it
  connected to nothing and showed Rerun's welcome page ("Click + to add a recording"). Here the url and size are
  part of the state the widget is created with.
- **The internet.** The viewer asks GitHub for the latest Rerun on start
  (``https://api.github.com/repos/rerun-io/rerun/releases/latest``: ``net::ERR_NAME_NOT_RESOLVED`` and
  ``TypeError: Failed to fetch`` offline). Here :data:`OFFLINE_GUARD` shadows ``fetch`` inside the viewer's own
  module (nothing else in the page is touched): only ``data:``, ``blob:``, this page's origin and the loopback
  (where the recording is served) go through; anything else is answered at once with a 503, without a request.
- **A print.** ``rerun_notebook`` prints a line when imported with ``RERUN_NOTEBOOK_ASSET=inline``; silenced.

The viewer reads the recording from its gRPC server (:attr:`studio.review.recording.ProjectRecording.server_url`,
127.0.0.1 only), which keeps what was logged for viewers that connect late (a reloaded page) and streams the rest as
it is logged. ``studio.review`` sets ``RERUN_NOTEBOOK_ASSET=inline`` before this module imports rerun_notebook.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from collections.abc import Mapping
from typing import Any

from studio.errors import StudioError

DEFAULT_HEIGHT = 560  # px; the width is always the output area's (100 %)
MIN_HEIGHT = 240  # px; below this the viewer's panels do not fit
MAX_HEIGHT = 2000  # px

# Prepended to the viewer's ES module: a module-level `fetch` that the viewer's code (it calls plain `fetch(...)`)
# finds before the page's. Keep it free of top-level names other than `fetch` and `__shadowStudioFetch`.
OFFLINE_GUARD = """// Shadow Studio: this viewer never reaches the internet (studio/review/notebook_viewer.py).
const __shadowStudioFetch = globalThis.fetch.bind(globalThis);
const fetch = (input, init) => {
  const raw = typeof input === "string" ? input : (input && input.url) || String(input);
  let url;
  try { url = new URL(raw, globalThis.location.href); } catch (e) { return __shadowStudioFetch(input, init); }
  const host = url.hostname.replace(/^\\[|\\]$/g, "");
  const local = url.protocol === "data:" || url.protocol === "blob:" || url.origin === globalThis.location.origin
    || host === "localhost" || host === "::1" || /^127\\./.test(host);
  if (!local) {  // answered here, as a server that is down would: the viewer logs it quietly and carries on
    console.debug(`Shadow Studio: the Rerun viewer works offline; not fetching ${url.origin}${url.pathname}`);
    return Promise.resolve(new Response(null, { status: 503, statusText: "offline (Shadow Studio)" }));
  }
  return __shadowStudioFetch(input, init);
};
"""

_viewer_class: type | None = None


class _QuietHere:
    """A stand-in for ``sys.stdout`` that drops what this thread writes and passes the other threads' writes on (a
    viewer made in a background thread must not swallow the notebook's own output meanwhile)."""

    def __init__(self, out: Any):
        self.out, self.thread = out, threading.current_thread()

    def write(self, text: str) -> int:
        return len(text) if threading.current_thread() is self.thread else self.out.write(text)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.out, name)


def _quiet() -> contextlib.AbstractContextManager:
    return contextlib.redirect_stdout(_QuietHere(sys.stdout))


class NotebookViewerError(StudioError):
    """The notebook viewer cannot be made here (the message says what to install)."""


def viewer_class() -> type:
    """``rerun_notebook.Viewer`` with :data:`OFFLINE_GUARD` in its module (made once; a URL asset is left alone:
    whoever set ``RERUN_NOTEBOOK_ASSET`` to a URL chose to fetch the viewer)."""
    global _viewer_class
    if _viewer_class is None:
        try:
            with _quiet():  # its "Loading inline widget ..." line
                import rerun_notebook
        except ImportError as e:
            raise NotebookViewerError(f"the Rerun viewer in the notebook needs the rerun-notebook package ({e}): "
                                      "pip install rerun-notebook") from None  # fmt: skip
        esm, inline = rerun_notebook.ESM_MOD, rerun_notebook.ASSET_ENV == rerun_notebook.ASSET_MAGIC_INLINE
        if not inline and os.environ.get("RERUN_NOTEBOOK_ASSET") == rerun_notebook.ASSET_MAGIC_INLINE:
            # imported before studio.review set the variable, so it would fetch its module from the internet
            with _quiet():
                esm, inline = rerun_notebook._inline_widget(), True
        attrs: dict[str, Any] = {"__module__": __name__, "__doc__": "rerun_notebook.Viewer, offline (module doc)."}
        if inline:
            attrs["_esm"] = OFFLINE_GUARD + esm
        _viewer_class = type("StudioRerunViewer", (rerun_notebook.Viewer,), attrs)
    return _viewer_class


def clamp_height(height: int) -> int:
    """``height`` px within [:data:`MIN_HEIGHT`, :data:`MAX_HEIGHT`]."""
    return max(MIN_HEIGHT, min(MAX_HEIGHT, int(height)))


def notebook_viewer(
    url: str, height: int = DEFAULT_HEIGHT, panels: Mapping[str, str] | None = None, theme: str | None = None
) -> Any:
    """The viewer widget on the gRPC stream at ``url`` (``rerun+http://127.0.0.1:PORT/proxy``), 100 % wide and
    ``height`` px tall (its ``_height`` trait resizes it). ``panels``: panel states by name (``"top"``,
    ``"blueprint"``, ``"selection"``, ``"time"`` → ``"expanded"``, ``"collapsed"`` or ``"hidden"``); ``theme``:
    ``"dark"``, ``"light"`` or ``"system"`` (None: the viewer's own). A :class:`NotebookViewerError` when
    rerun-notebook is missing."""
    cls = viewer_class()
    state: dict[str, Any] = {"_url": url, "_width": "auto", "_height": clamp_height(height)}
    if panels:
        state["_panel_states"] = dict(panels)
    if theme:
        state["_theme"] = theme
    # the state goes in the keyword arguments (the widget is created with it: module doc); Viewer.__init__ then sets
    # the same values again, which sends nothing
    return cls(width="auto", height=state["_height"], url=url, panel_states=None, theme=theme, **state)
