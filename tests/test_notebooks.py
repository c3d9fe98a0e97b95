"""Every notebook in notebooks/ runs headless top to bottom (nbclient, the python3 kernel of ipykernel) without an
error; the studio notebook opens the studio on the project it is given through the environment."""

from __future__ import annotations

from pathlib import Path

import nbformat
import pytest
from nbclient import NotebookClient
from studio.assets import asset

from studio.project.project import Project

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
WALKTHROUGHS = ["01_still.ipynb", "02_video.ipynb", "03_playback.ipynb"]
CELL_TIMEOUT_S = 120


def execute(name: str, cwd: Path) -> nbformat.NotebookNode:
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    NotebookClient(
        nb, timeout=CELL_TIMEOUT_S, kernel_name="python3", resources={"metadata": {"path": str(cwd)}}
    ).execute()
    return nb


def outputs(nb: nbformat.NotebookNode) -> list[dict]:
    return [o for c in nb.cells if c.cell_type == "code" for o in c.outputs]


def test_the_notebooks_are_the_ones_listed():
    assert sorted(p.name for p in NOTEBOOKS.glob("*.ipynb")) == sorted(WALKTHROUGHS + ["studio.ipynb"])


@pytest.mark.slow
@pytest.mark.parametrize("name", WALKTHROUGHS)
def test_walkthrough_runs(name, tmp_path):
    nb = execute(name, tmp_path)
    assert not [o for o in outputs(nb) if o.output_type == "error"]
    assert all(c.execution_count for c in nb.cells if c.cell_type == "code")


@pytest.mark.slow
def test_studio_notebook_opens_the_given_project(tmp_path, monkeypatch):
    project = Project.create(tmp_path / "mine.shadow", sources=[asset("targets/asl_o.jpeg")])
    monkeypatch.setenv("SHADOW_STUDIO_PROJECT", str(project.path))  # the kernel inherits it
    nb = execute("studio.ipynb", tmp_path)
    outs = outputs(nb)
    assert not [o for o in outs if o.output_type == "error"]
    views = [o for o in outs if "application/vnd.jupyter.widget-view+json" in o.get("data", {})]
    assert len(views) == 1  # the studio (the second cell opens nothing until MY_PROJECT is set)
    state = nb.metadata["widgets"]["application/vnd.jupyter.widget-state+json"]["state"]
    texts = [m["state"]["value"] for m in state.values() if isinstance(m["state"].get("value"), str)]
    assert any(str(project.path) in t for t in texts)  # the header names the project it opened
    tabs = [m["state"] for m in state.values() if m["model_name"] == "TabModel"]
    titles = ["Targets", "Keyframes", "Masks", "Weights", "Optimise", "Review", "Jog", "Rig", "Live", "Export"]
    assert tabs[0]["titles"] == titles
