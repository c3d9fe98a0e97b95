"""The studio: every panel of one project in tabs (``open_studio()`` in a notebook cell).

    from widgets.app import open_studio
    open_studio()                       # the bundled demo project (made on first use in ~/.cache/shadow-studio)
    open_studio("my_show.shadow")       # your own project (``shadow-studio project new`` makes one)

The panels come in the artist's order (:data:`PANELS`); each lives in its own module ``widgets.<module>`` exposing
``<module>_panel(state)``, imported when the studio is built. A panel that cannot be built (its module missing, or
an error while building it) becomes a label ``"<Name>: unavailable (<reason>)"`` so the studio always opens.
``shadow-studio lab`` passes its project to the notebook through :data:`PROJECT_ENV`.
"""

from __future__ import annotations

import html
import importlib
import logging
import os
from pathlib import Path

import ipywidgets as w

from studio.errors import StudioError
from widgets.state import StudioState

log = logging.getLogger(__name__)

PANELS = (
    ("Targets", "targets"),
    ("Keyframes", "keyframes"),
    ("Masks", "masks"),
    ("Weights", "weights"),
    ("Optimise", "optimise"),
    ("Review", "review"),
    ("Jog", "jog"),
    ("Rig", "rig"),
    ("Live", "live"),
    ("Export", "export"),
)  # (title, module in widgets/), in the order an artist works
PROJECT_ENV = "SHADOW_STUDIO_PROJECT"  # environment variable: the project open_studio() opens when given none
CLIP_ENV = "SHADOW_STUDIO_CLIP_WEIGHTS"  # environment variable: a local open_clip checkpoint for the CLIP terms


def unavailable(name: str, reason: str) -> w.Widget:
    """The placeholder of a panel that could not be built."""
    return w.Label(f"{name}: unavailable ({reason})")


def build_panel(state: StudioState, name: str, module: str) -> w.Widget:
    """``widgets.<module>.<module>_panel(state)`` as a widget (a function's widget or a class's ``.widget``), or the
    :func:`unavailable` label saying why not."""
    full = f"widgets.{module}"
    try:
        mod = importlib.import_module(full)
    except ModuleNotFoundError as e:
        reason = "not built yet" if e.name == full else f"needs {e.name}"
        log.warning("panel %s: %s", name, reason)
        return unavailable(name, reason)
    except Exception as e:  # a broken panel module must not stop the studio
        log.exception("panel %s: its module failed to import", name)
        return unavailable(name, f"{type(e).__name__}: {e}")
    make = getattr(mod, f"{module}_panel", None)
    if make is None:
        return unavailable(name, f"{full} has no {module}_panel")
    try:
        panel = make(state)
    except Exception as e:  # a StudioError says what to do; anything else is a bug, logged with its traceback
        if not isinstance(e, StudioError):
            log.exception("panel %s failed to build", name)
        return unavailable(name, f"{type(e).__name__}: {e}")
    widget = getattr(panel, "widget", panel)
    if not isinstance(widget, w.Widget):
        return unavailable(name, f"{module}_panel gave {type(widget).__name__}, not a widget")
    state.extras.setdefault("panels", {})[module] = panel
    return widget


def _import_panels() -> None:
    """Import every panel's module before any panel is built: panels start background work (the recording, the
    meshcat scene, torch), and imports made meanwhile in this thread wait on Python's import lock and the GIL (a
    240-frame project's studio opened in 3.9–4.6 s, 1.9–2.2 s this way). A module that fails is left for
    :func:`build_panel` to report."""
    for _, module in PANELS:
        try:
            importlib.import_module(f"widgets.{module}")
        except Exception:  # noqa: BLE001 - build_panel says why, in the panel's place
            log.debug("panel module widgets.%s did not import", module, exc_info=True)


# a button or a field's description is at least as wide as its words (ipywidgets' fixed widths cut "save as
# keyframe" to "save as keyfra…" and "sampling Hz" to "sampling …")
STYLE = "<style>.shadow-studio button.jupyter-button, .shadow-studio .widget-label { min-width: max-content; }</style>"


def _header(state: StudioState) -> w.HTML:
    p = state.project
    text = f"{STYLE}<b>Shadow Studio</b> — {html.escape(p.state.title)} <code>{html.escape(str(p.path))}</code>"
    missing = ", ".join(html.escape(m.path) for m in p.missing_sources)
    if missing:
        text += f"<br>missing sources (relink them in Targets): {missing}"
    return w.HTML(text)


def studio_app(state_or_path: StudioState | str | Path) -> w.Widget:
    """Every panel of one project in tabs: a :class:`StudioState` or a project folder ``NAME.shadow`` (opened with
    its job queue). The returned widget keeps the state as ``.studio_state``. ``$SHADOW_STUDIO_CLIP_WEIGHTS``
    becomes ``state.extras["clip_weights"]`` unless that is set already."""
    state = state_or_path if isinstance(state_or_path, StudioState) else StudioState.open(state_or_path)
    if os.environ.get(CLIP_ENV) and not state.extras.get("clip_weights"):
        state.extras["clip_weights"] = os.environ[CLIP_ENV]
    _import_panels()
    panels = [build_panel(state, name, module) for name, module in PANELS]
    tabs = w.Tab(children=panels, titles=[name for name, _ in PANELS])
    app = w.VBox([_header(state), tabs])
    app.add_class("shadow-studio")
    app.studio_state = state
    return app


def project_path(path: str | Path | None = None, folder: str | Path | None = None) -> Path:
    """The project ``open_studio`` opens: ``path``, else ``$SHADOW_STUDIO_PROJECT``, else the demo project in
    ``folder`` (default ``~/.cache/shadow-studio``; made on first use)."""
    if path is None:
        path = os.environ.get(PROJECT_ENV) or None
    if path is not None:
        return Path(path).expanduser()
    from studio.project.demo import demo_project

    project, _ = demo_project(folder)
    return project.path


def open_studio(path: str | Path | None = None, folder: str | Path | None = None) -> w.Widget:
    """The studio on a project (see :func:`project_path`); a project that cannot be opened gives a message saying
    why, never a traceback."""
    try:
        return studio_app(project_path(path, folder))
    except StudioError as e:
        log.warning("the studio could not open: %s", e)
        return w.HTML(f"<b>Shadow Studio</b>: could not open the project: {html.escape(str(e))}")
