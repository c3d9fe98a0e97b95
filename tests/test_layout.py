"""DESIGN §3's import rules, read from the code's own imports at every level: module level, inside functions and
under ``TYPE_CHECKING`` (a cycle hidden behind a function-level import is still a cycle)."""

from __future__ import annotations

import ast
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# stage → the stages it may import (DESIGN §3: foundation ← sim ← targets, learn ← imitate, motion ← evaluate,
# review ← jobs ← project ← widgets, cli; arrows only downward)
ALLOWED = {
    "sim": set(),
    "targets": {"sim"},
    "learn": {"sim"},
    "imitate": {"sim", "targets", "learn"},
    "motion": {"sim"},
    "evaluate": {"sim", "targets", "learn", "imitate", "motion"},
    "review": {"sim", "targets", "learn", "imitate", "motion"},
    "jobs": {"sim", "targets", "learn", "imitate", "motion", "evaluate", "review"},
    "project": {"sim", "targets", "learn", "imitate", "motion", "evaluate", "review", "jobs"},
    "cli": {"sim", "targets", "learn", "imitate", "motion", "evaluate", "review", "jobs", "project"},
}
FOUNDATION = {
    "studio.errors",  # typed errors, and the progress and cancel protocol of every long call
    "studio.atomic",  # the one atomic writer, and the one bounded JSON reader
    "studio.assets",
    "studio.home",
}  # DESIGN §3's foundation (learn.fanout + learn.ray_cluster, many items through one task in this process, on local
# processes or on Ray, are learn's: no stage below it uses them; targets.path_checks is the footage stage's)


def modules() -> dict[str, Path]:
    out = {}
    for top in ("studio", "hardware", "widgets"):
        for path in (ROOT / top).rglob("*.py"):
            parts = path.relative_to(ROOT).with_suffix("").parts
            out[".".join(p for p in parts if p != "__init__")] = path
    out.update({f"studio.assets.{p.stem}": p for p in (ROOT / "assets").glob("*.py") if p.stem != "__init__"})
    out["studio.assets"] = ROOT / "assets" / "__init__.py"
    return out


def _package(module: str, path: Path) -> str:
    return module if path.name == "__init__.py" else module.rpartition(".")[0]


def imports(path: Path, module: str = "", top_level_only: bool = False, known: frozenset[str] = frozenset()) -> set:
    """Every module ``path`` imports (``from a import b`` names ``a.b`` too when that is a module in ``known``);
    relative imports resolved against ``module``."""
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else ast.walk(tree)
    found: set[str] = set()
    for node in nodes:
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = _package(module, path).split(".")
                pkg = pkg[: len(pkg) - node.level + 1]
                base = ".".join([*pkg, base] if base else pkg)
            if base:
                found.add(base)
                found.update(f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in known)
    return found


def stage(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if parts[0] == "studio" and len(parts) > 1 and parts[1] in ALLOWED else None


def graph() -> dict[str, set[str]]:
    mods = modules()
    known = frozenset(mods)
    return {m: {i for i in imports(p, m, known=known) if i in mods and i != m} for m, p in mods.items()}


def test_stages_import_only_downward():
    wrong = []
    for mod, path in modules().items():
        here = stage(mod)
        if here is None:
            continue
        for imp in imports(path, mod):
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
        "hardware": (
            "hardware",
            "studio.cli",
            "studio.project.play",
            "studio.project.live",
            "studio.project.capture",
            "studio.project.rig_calibration",
            "studio.project.show_capture",
            "widgets",
        ),  # DESIGN §3: project's play and capture steps
        "widgets": ("widgets",),
        "ray": (
            "studio.learn.ray_cluster",
            "studio.learn.ray_train",
        ),  # DESIGN §3: only the module that distributes work, only when asked
    }
    wrong = []
    for mod, path in modules().items():
        for imp in imports(path, mod):
            allowed = rules.get(imp.split(".")[0])
            if allowed is not None and not mod.startswith(allowed or ("\0",)):
                wrong.append(f"{mod} imports {imp}")
    assert not wrong, wrong


def test_hardware_uses_only_the_hand_and_the_show():
    """``hardware`` stands beside the engine: of ``studio`` it reads only the hand (sim) and the show file (motion),
    plus the foundation (DESIGN §3)."""
    ok = ("studio.sim", "studio.motion", *FOUNDATION)
    wrong = [
        f"{mod} imports {imp}"
        for mod, path in modules().items()
        if mod.startswith("hardware")
        for imp in imports(path, mod)
        if imp.split(".")[0] == "studio" and imp != "studio" and not imp.startswith(ok)
    ]
    assert not wrong, wrong


def test_emulator_is_imported_lazily():
    """The emulator (pty, termios: POSIX only) is never imported at module level outside hardware.emulator."""
    eager = [m for m, p in modules().items() if "hardware.emulator" in imports(p, m, top_level_only=True)]
    assert not eager, eager


def cycle(g: dict[str, set[str]]) -> list[str] | None:
    """One import cycle of ``g`` as a path ``[a, b, …, a]``, or None."""
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> list[str] | None:
        state[m] = 1
        stack.append(m)
        for n in sorted(g.get(m, ())):
            if state.get(n) == 1:
                return [*stack[stack.index(n) :], n]
            if n not in state and (found := visit(n)):
                return found
        stack.pop()
        state[m] = 2
        return None

    for m in sorted(g):
        if m not in state and (found := visit(m)):
            return found
    return None


def test_no_import_cycles_at_any_level():
    found = cycle(graph())
    assert found is None, "import cycle: " + " → ".join(found)


def test_the_cycle_finder_sees_function_level_and_type_checking_imports(tmp_path):
    """The rule above must fail on a cycle that only a function-level or TYPE_CHECKING import closes."""
    a = tmp_path / "a.py"
    a.write_text("import b\n")
    b = tmp_path / "b.py"
    b.write_text(
        textwrap.dedent("""
        from typing import TYPE_CHECKING
        if TYPE_CHECKING:
            from c import X
        def f():
            from a import g
    """)
    )
    known = frozenset({"a", "b", "c"})
    g = {"a": imports(a, "a", known=known), "b": imports(b, "b", known=known), "c": set()}
    assert cycle(g) == ["a", "b", "a"]
    assert "c" in g["b"]


def test_public_api_names_resolve():
    import studio

    missing = [name for name in studio.__all__ if getattr(studio, name, None) is None]
    assert not missing, missing
    assert set(studio.__all__) <= set(dir(studio))
