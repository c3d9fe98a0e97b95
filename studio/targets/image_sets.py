"""Target sets on disk: the image files of a folder (and its sub-folders), and a numbered image's class and
number (MPEG-7's ``camel-1.gif``), for the tables and benchmarks that run many targets (:mod:`studio.evaluate`).

IO only (the folder listing); one image's loading is :mod:`studio.targets.images`.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from studio.errors import TargetError
from studio.targets.images import IMAGE_SUFFIXES
from studio.targets.path_checks import check_text, existing_paths


def find_target_files(folder: str | Path) -> list[Path]:
    """Image files directly in ``folder`` (sorted by name), by suffix (:data:`IMAGE_SUFFIXES`)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise TargetError(f"target folder not found: {folder}")
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES)


def image_class(path: str | Path) -> str:
    """A numbered image's class: its name before the last ``-`` (MPEG-7's ``camel-1.gif``, ``rat-01.gif`` → ``camel``,
    ``rat``); a name without ``-`` is its own class."""
    return Path(path).stem.rsplit("-", 1)[0]


def image_number(path: str | Path) -> int | None:
    """A numbered image's number within its class (``rat-03.gif`` → 3), None when its name has none."""
    _, sep, tail = Path(path).stem.rpartition("-")
    return int(tail) if sep and tail.isdigit() else None


def first_per_class(files: Sequence[Path], n: int) -> list[Path]:
    """The first ``n`` files (in the given order) of each class (:func:`image_class`)."""
    seen: dict[str, int] = {}
    out = []
    for f in files:
        cls = image_class(f)
        if seen.get(cls, 0) < n:
            seen[cls] = seen.get(cls, 0) + 1
            out.append(f)
    return out


def gather_targets(
    paths: Sequence[str | Path], per_folder: int | None = None, per_class: int | None = None
) -> list[Path]:
    """Target files from files and folders: a folder gives its images and those of each sub-folder (first
    ``per_folder`` of each, by name; of those, the first ``per_class`` of each :func:`first_per_class` class).
    Raises :class:`TargetError` for a missing path or when nothing is found."""
    if per_folder is not None and per_folder < 1:
        raise ValueError(f"per_folder (images per folder) must be at least 1, not {per_folder}")
    if per_class is not None and per_class < 1:
        raise ValueError(f"per_class (images per class) must be at least 1, not {per_class}")
    out: list[Path] = []
    for p in existing_paths(paths, "target file or folder"):
        if p.is_file():
            out.append(p)
            continue
        folders = [p, *sorted(d for d in p.iterdir() if d.is_dir())]
        found = [f for d in folders for f in find_target_files(d)[:per_folder]]
        if per_class is not None:
            found = first_per_class(found, per_class)
        if not found:
            raise TargetError(f"no target images ({', '.join(IMAGE_SUFFIXES)}) in {p} or its sub-folders")
        out += found
    check_text(out, "target file name")  # named in the tables written at the end: refused now, not then
    return out
