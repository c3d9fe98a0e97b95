"""What every panel writes: times as ``0.80 s``, counts that agree with their word, stages in the artist's words,
and never a command-line flag, a traceback or a float's raw digits in what a notebook user reads (DESIGN §5.14)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest
from studio.assets import asset

from studio.errors import count, plural
from studio.project.jobs import queue_for
from studio.project.project import Project
from studio.targets.video import VideoConfig
from widgets.state import StudioState
from widgets.words import bar_label, late_lines, seconds, span, stage

WIDGETS = Path(__file__).resolve().parents[1] / "widgets"
FLAG = re.compile(r"(?<![\w-])--[a-z][a-z-]+")  # --allow-late, --clip-weights
RAW_FLOAT = re.compile(r"\d\.\d{6,}")  # 0.7999999999999999


def test_times_counts_and_stages_in_words():
    assert seconds(0.7 + 0.1) == "0.80 s" and seconds(None) == "-" and seconds(2.5, 3) == "2.500 s"
    assert span(0.4, 0.7999999999999999) == "0.40–0.80 s" and span(1.0, 1.001) == "1.00 s"
    assert count(1, "keyframe") == "1 keyframe" and count(5, "keyframe") == "5 keyframes"
    assert count(0, "pass") == "0 passes" and count(200_000, "pose") == "200,000 poses"
    assert plural("collides", 2) == "collide" and plural("is", 3) == "are" and plural("belongs", 1) == "belongs"
    assert stage("index", 200_000) == "building the retrieval index of 200,000 poses (first use only, cached)"
    assert stage("keyframe 2/5: index", 10).startswith("keyframe 2/5: building the retrieval index of 10 poses")
    assert stage("search", 40) == "search"
    assert stage("keyframe 1/3: compile", 1) == (
        "keyframe 1/3: compiling the renderer's and the losses' kernels (first run after this install only)"
    )
    assert bar_label("keyframe 1/3: index") == "retrieval index (first use)" and bar_label("search") == "search"
    assert bar_label("compile") == "compiling kernels (first run)"  # not the index's words (the bar labels did)
    assert stage("together", 400) == "refining the keyframes together, within their reach on the show's clock"
    assert bar_label("together") == "keyframes together"
    late = {"from_frame": None, "to_frame": 0, "from_keyframe": None, "to_keyframe": 3, "t_start": 0.0,
            "t_end": 0.05, "given_s": 0.05, "needed_s": 0.7999999999999999}  # fmt: skip
    assert late_lines([late]) == ["home → frame 0 (home → k3) at 0.00 s: needs 0.80 s, given 0.05 s"]


def shown_strings(path: Path) -> list[tuple[int, str]]:
    """The string literals of a module that are not docstrings (what it can show), with their lines."""
    tree = ast.parse(path.read_text())
    docs = {
        id(node.body[0].value)
        for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
        and node.body and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)
    }  # fmt: skip
    return [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs
    ]


@pytest.mark.parametrize("module", sorted(p.name for p in WIDGETS.glob("*.py")))
def test_no_panel_names_a_command_line_flag(module):
    said = [(line, text) for line, text in shown_strings(WIDGETS / module) if FLAG.search(text)]
    assert said == [], f"{module} shows a flag to a notebook user (say what to tick or type instead): {said}"


MAYBE_PLURAL = re.compile(r"[a-z]\(s\)")  # keyframe(s): a count that does not agree with its word


@pytest.mark.parametrize("package", ["studio", "widgets", "hardware"])
def test_no_message_writes_a_word_with_s_in_brackets(package):
    """Every message counts in words that agree with the number (``studio.errors.count``), never ``keyframe(s)``."""
    root = WIDGETS.parent / package
    said = [(str(p.relative_to(root.parent)), line, text) for p in sorted(root.rglob("*.py"))
            for line, text in shown_strings(p) if MAYBE_PLURAL.search(text)]  # fmt: skip
    assert said == [], f"write these counts with studio.errors.count / plural: {said}"


def visible(widget) -> list[str]:
    """Every text a person can read on ``widget`` and its children: values, descriptions, tooltips, options."""
    out, todo = [], [widget]
    while todo:
        x = todo.pop()
        for name in ("value", "description", "tooltip", "placeholder"):
            v = getattr(x, name, None)
            if isinstance(v, str):
                out.append(v)
        for option in getattr(x, "options", ()) or ():
            out.append(str(option[0] if isinstance(option, tuple) else option))
        todo.extend(getattr(x, "children", ()) or ())
    return out


def test_every_panel_reads_in_the_notebooks_words(tmp_path):
    from widgets.export import export_panel
    from widgets.jog import jog_panel
    from widgets.keyframes import KeyframesPanel
    from widgets.optimise import OptimiseConfig, optimise_panel
    from widgets.targets import TargetsPanel
    from widgets.weights import weights_panel

    project = Project.create(tmp_path / "w.shadow", [asset("targets/asl_o.jpeg"), asset("videos/muybridge_horse.gif")],
                             video=VideoConfig(size=48, hz=4.0))  # fmt: skip
    state = StudioState(project, queue_for(project))
    panels = []
    try:
        optimise = optimise_panel(state, OptimiseConfig(warm_index=False))
        panels = [TargetsPanel(state), KeyframesPanel(state), weights_panel(state), optimise, export_panel(state),
                  jog_panel(state)]  # fmt: skip
        state.select(frame=len(project.frames) - 1)
        panels[0].path.value = str(tmp_path / "nowhere.png")
        panels[0].add_path.click()  # an error: a message, in words
        panels[4].plan_button.click()  # no results yet: a message, in words
        texts = [t for p in panels for t in visible(p.widget)]
        joined = "\n".join(texts)
        assert "no such file" in joined and "no result for keyframe" in joined
        assert not FLAG.search(joined) and "Traceback" not in joined and "extras[" not in joined
        assert not RAW_FLOAT.search(joined), RAW_FLOAT.findall(joined)
        assert not re.search(r"\b1 (keyframes|frames|transitions|samples)\b", joined) and "(s)" not in joined
    finally:
        for p in panels:
            p.close()
        state.close()
