"""Checks on the paths a person gives, made once before any long work (DESIGN §5.8):

- :func:`check_outputs`: where a verb may write: never onto a file it reads, never inside a folder it reads (a
  project being exported, a frame folder being imitated), and only where a file can be made (the one way every verb
  with ``--out`` does it);
- :func:`check_text`: a name that is not text (bytes of another encoding, which Python carries as lone surrogates)
  is refused at once, where it would otherwise fail when printed or written into a JSON file at the very end;
- :func:`existing_paths`: the sources a verb gathers from its arguments are each a file or a folder that is there.

A path is compared by what it names on disk (``os.path.samefile`` when both exist: a symlink or a hard link to the
input is the input), else by its resolved form (``os.path.realpath``).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

from studio.atomic import name_max
from studio.errors import StudioError, TargetError

PathLike = str | os.PathLike


class OutputPathError(StudioError):
    """An output would overwrite an input, land inside a folder being read, or cannot be made where it is asked."""


class NameNotText(StudioError):
    """A file name (or another word) is not UTF-8 text."""


def shown(name: str | os.PathLike) -> str:
    """``name`` as printable text: bytes that are not UTF-8 as ``\\xNN`` (``caf\\xe9.png``)."""
    return os.fsencode(name).decode("utf-8", "backslashreplace")


def check_text(names: Iterable[str | os.PathLike], what: str = "file name") -> None:
    """Raise :class:`NameNotText` naming the first of ``names`` that is not UTF-8 text."""
    for name in names:
        try:
            os.fspath(name).encode("utf-8")
        except UnicodeEncodeError:
            raise NameNotText(
                f"{shown(name)}: the {what} is not UTF-8 text (another encoding?); rename it with UTF-8 characters"
            ) from None


def check_outputs(
    outputs: Iterable[PathLike | None], inputs: Iterable[PathLike | None] = (), folders: Iterable[PathLike | None] = ()
) -> None:
    """Raise :class:`OutputPathError` when an output (a file to write; None is skipped) is one of ``inputs`` (files
    or folders read), the same file as another output, lies inside one of ``folders`` (folders read whose content an
    output must not join: a project, a frame folder), or cannot be made (its folder is a file or not writable, or
    a name is longer than the file system allows)."""
    outs = [Path(o) for o in outputs if o is not None]
    ins = [Path(i) for i in inputs if i is not None]
    for n, out in enumerate(outs):
        for inp in ins:
            if _same(out, inp):
                what = "both an input and an output" if out == inp else f"the same file as the input {inp}"
                raise OutputPathError(f"{out} is {what}: writing it would destroy the input; write elsewhere")
        for other in outs[:n]:
            if _same(out, other):
                what = f"{out} is named twice" if out == other else f"{other} and {out} are the same file"
                raise OutputPathError(f"{what}: give each output its own name")
        for folder in folders:
            if folder is not None and _inside(out, Path(folder)):
                raise OutputPathError(f"{out} lies inside {folder}, which is being read: write it outside that folder")
        _check_creatable(out)


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet): compare what they resolve to
        return os.path.realpath(a) == os.path.realpath(b)


def _inside(path: Path, folder: Path) -> bool:
    """Whether ``path`` is ``folder`` or lies beneath it (both resolved)."""
    p, f = Path(os.path.realpath(path)), Path(os.path.realpath(folder))
    return p == f or f in p.parents


def _check_creatable(out: Path) -> None:
    """Refuse ``out`` when its nearest existing folder is a file or not writable, or a name in it is too long."""
    parents = list(out.absolute().parents)
    folder = next((p for p in parents if os.path.isdir(p)), Path("/"))
    limit = name_max(folder)
    for part in out.parts:
        if len(os.fsencode(part)) > limit:
            raise OutputPathError(
                f"{out}: the name {part[:24]}… is {len(os.fsencode(part))} bytes; this file system allows {limit}"
            )
    blocker = next((p for p in parents if os.path.lexists(p) and not os.path.isdir(p)), None)
    if blocker is not None:
        raise OutputPathError(f"{out} cannot be made: {blocker} is a file, not a folder")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputPathError(f"{out} cannot be written: the folder {folder} is not writable")


def existing_paths(paths: Iterable[PathLike], what: str) -> list[Path]:
    """``paths`` as :class:`Path` objects, each an existing file or folder; :class:`TargetError` "<what> not found:
    <path>" for the first that is neither (what gathers sources from arguments checks them first)."""
    out = [Path(p) for p in paths]
    for p in out:
        if not p.is_file() and not p.is_dir():
            raise TargetError(f"{what} not found: {p}")
    return out
