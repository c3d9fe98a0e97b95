"""DESIGN §3's import rules, read from the code's own imports (module level and inside functions)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# stage → the stages it may import (DESIGN §3: arrows only downward; errors and atomic are the foundation)
ALLOWED = {
    "sim": set(),
    "learn": {"sim"},
    "imitate": {"sim", "learn"},
    "motion": {"sim"},
    "evaluate": {"sim", "learn", "imitate", "motion"},
    "review": {"sim", "learn", "imitate", "motion", "evaluate"},
    "project": {"sim", "learn", "imitate", "motion", "evaluate", "review"},
    "cli": {"sim", "learn", "imitate", "motion", "evaluate", "review", "project"},
}
FOUNDATION = {"studio.errors", "studio.atomic", "studio.assets", "studio.home"}


def modules() -> dict[str, Path]:
    out = {}
    for top in ("studio", "hardware", "widgets"):
        for path in (ROOT / top).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(p for p in parts if p != "__init__")] = path
    return out


def imports(path: Path, top_level_only: bool = False) -> set[str]:
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else ast.walk(tree)
    found: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return found


def stage(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "studio" and len(parts) > 1 and parts[1] in ALLOWED else None


def test_stages_import_only_downward():
    wrong = []
    for mod, path in modules().items():
        here = stage(mod)
        if here is None:
            continue
        for imp in imports(path):
            there = stage(imp)
            if imp.split(".")[0] == "studio" and imp not in FOUNDATION and there not in ALLOWED[here] | {here}:
                wrong.append(f"{mod} imports {imp}")
    assert not wrong, wrong


def test_io_libraries_stay_at_their_edges():
    rules = {  # library → module prefixes that may import it
        "rerun": ("studio.review",),
        "meshcat": ("studio.review",),
        "serial": ("hardware",),
        "ipywidgets": ("widgets",),
        "ipycanvas": ("widgets",),
        "hardware": ("hardware", "studio.cli", "studio.project.jobs", "widgets"),
        "widgets": ("widgets",),
    }
    wrong = []
    for mod, path in modules().items():
        for imp in imports(path):
            allowed = rules.get(imp.split(".")[0])
            if allowed and not mod.startswith(allowed):
                wrong.append(f"{mod} imports {imp}")
    assert not wrong, wrong


def test_emulator_is_imported_lazily():
    """The emulator (pty, termios: POSIX only) is never imported at module level outside hardware.emulator."""
    eager = [m for m, p in modules().items() if "hardware.emulator" in imports(p, top_level_only=True)]
    assert not eager, eager


def test_no_module_level_cycles():
    mods = modules()
    graph = {m: {i for i in imports(p, top_level_only=True) if i in mods and i != m} for m, p in mods.items()}
    state: dict[str, int] = {}

    def visit(m: str, trail: list[str]) -> None:
        state[m] = 1
        for n in graph[m]:
            if state.get(n) == 1:
                raise AssertionError("import cycle: " + " → ".join([*trail[trail.index(n) :], n]))
            if n not in state:
                visit(n, [*trail, n])
        state[m] = 2

    for m in graph:
        if m not in state:
            visit(m, [m])


def test_public_api_names_resolve():
    import studio

    missing = [name for name in studio.__all__ if getattr(studio, name, None) is None]
    assert not missing, missing
    assert set(studio.__all__) <= set(dir(studio))
