"""The studio app (widgets.app): every panel in the artist's order, a placeholder naming the reason for a panel that
cannot be built, the demo project made on first use and reopened after, and a project from the environment."""

from __future__ import annotations

import ipywidgets as w
import pytest
from studio.assets import asset

from studio.project.demo import PROJECT_NAME, demo_project
from studio.project.project import Project
from widgets import app
from widgets.state import StudioState


@pytest.fixture
def state(tmp_path):
    project = Project.create(tmp_path / "still.shadow", sources=[asset("targets/asl_o.jpeg")])
    s = StudioState.open(project.path)
    yield s
    s.close()


def tab_of(studio: w.Widget) -> w.Tab:
    return next(c for c in studio.children if isinstance(c, w.Tab))


@pytest.mark.slow
def test_every_panel_in_order_and_a_placeholder_says_why(state, monkeypatch):
    def broken(_state):
        raise RuntimeError("the canvas is gone")

    import widgets.weights

    monkeypatch.setattr(widgets.weights, "weights_panel", broken)
    studio = app.studio_app(state)
    tab = tab_of(studio)
    assert tab.titles == (
        "Targets",
        "Keyframes",
        "Masks",
        "Weights",
        "Optimise",
        "Review",
        "Jog",
        "Rig",
        "Live",
        "Export",
    )
    assert len(tab.children) == 10 and all(isinstance(c, w.Widget) for c in tab.children)
    assert tab.children[3].value == "Weights: unavailable (RuntimeError: the canvas is gone)"
    assert studio.studio_state is state
    missing = app.build_panel(state, "Nothing", "no_such_panel")
    assert missing.value == "Nothing: unavailable (not built yet)"


def test_open_studio_makes_the_demo_once_then_reopens_it(tmp_path, monkeypatch):
    monkeypatch.delenv(app.PROJECT_ENV, raising=False)
    studio = app.open_studio(folder=tmp_path)
    state = studio.studio_state
    try:
        assert state.project.path == tmp_path / PROJECT_NAME
        assert [s.kind for s in state.project.sources] == ["still", "video"]
        assert "demo" in studio.children[0].value
    finally:
        state.close()
    project, fresh = demo_project(tmp_path)
    assert not fresh and project.path == tmp_path / PROJECT_NAME


def test_open_studio_reads_the_project_from_the_environment_and_reports_a_bad_one(state, tmp_path, monkeypatch):
    monkeypatch.setenv(app.PROJECT_ENV, str(state.project.path))
    assert app.project_path() == state.project.path
    monkeypatch.setenv(app.PROJECT_ENV, str(tmp_path / "nothing.shadow"))
    message = app.open_studio()
    assert isinstance(message, w.HTML) and "could not open the project" in message.value
    assert "nothing.shadow" in message.value


@pytest.mark.slow
def test_every_panels_code_is_imported_before_any_panel_starts_its_background_work(tmp_path):
    """Panels start background work (the recording, the meshcat scene, torch); imports the notebook's thread makes
    meanwhile wait on the import lock, so the studio imports every panel's module first (in a fresh interpreter:
    here the test process has imported them already)."""
    import subprocess
    import sys

    code = f"""
import sys
from widgets import app
from widgets.state import StudioState
from studio.project.project import Project
from studio.assets import asset
seen = []
real = app.build_panel
def watched(state, name, module):
    seen.append(all(f"widgets.{{m}}" in sys.modules for _, m in app.PANELS))
    return real(state, name, module)
app.build_panel = watched
project = Project.create({str(tmp_path / "p.shadow")!r}, sources=[asset("targets/asl_o.jpeg")])
state = StudioState.open(project.path)
app.studio_app(state)
print("ALL-IMPORTED-FIRST" if seen and seen[0] else "NOT-FIRST")
for panel in state.extras["panels"].values():
    getattr(panel, "close", lambda: None)()
state.close()
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert "ALL-IMPORTED-FIRST" in done.stdout, done.stdout[-2000:] + done.stderr[-3000:]


@pytest.mark.slow
def test_a_selection_reaches_every_tab_once_and_a_keyframe_click_keeps_its_keyframe(tmp_path):
    """In the whole studio, a click on a Keyframes card selects its keyframe and frame, told to every tab once (the
    Targets tab's scrubber, moved to that frame, used to select the frame again: every tab redrew twice and the
    keyframe was dropped); a selection that changes nothing tells no one."""
    from studio.targets.video import DEFAULT_VIDEO

    project = Project.create(tmp_path / "horse.shadow", sources=[DEFAULT_VIDEO])
    state = StudioState.open(project.path)
    try:
        app.studio_app(state)
        told: list[str] = []
        state.on_change(told.append)
        panel, last = state.extras["panels"]["keyframes"], state.project.keyframes[-1]
        assert state.selection.frame != last.representative
        panel.strip.children[-1].children[1].click()  # the last card's "select"
        assert (state.selection.frame, state.selection.keyframe) == (last.representative, last.id)
        assert told.count("selection") == 1
        told.clear()
        state.select(frame=last.representative, keyframe=last.id)
        assert told == []
    finally:
        for panel in state.extras.get("panels", {}).values():
            getattr(panel, "close", lambda: None)()
        state.close()
