"""What a project may touch: its own files inside its own folder, and sources that are plain files or folders.

A project folder is something people share (an archive from a colleague, a download), so nothing in it is trusted:

- **Project files** are named by ``project.json`` in exactly the shapes the writer makes (:data:`NAME`:
  ``masks/KIND-OWNER-HASH.png``, ``results/shadow-kK-HASH.png``, ``show-HASH.json``; no ``..``, no absolute path),
  and each is a regular file, never a symbolic link, read and deleted only there. A save deletes only files of
  those shapes (which only this project's saves make, one writer at a time) and the atomic writer's left-overs;
  anything else an artist keeps in the folder stays.
- **Subfolders** ``masks/``, ``results/`` and ``uploads/`` are real folders inside the project: a symlinked one
  (which would make a save write to, and delete from, the folder it points to) is refused with one line.
- **Sources** (the artist's stills, videos and frame folders, anywhere on disk) must be regular files or folders:
  a device, FIFO or socket (``/dev/zero``) would hang the hashing, so it is refused before it is opened.
- **A new project** goes only into a folder that does not exist or is empty; anything else is somebody's data.
"""

from __future__ import annotations

import os
import re
import stat
from pathlib import Path
from typing import Any

from studio.project.state import ProjectError

SUBFOLDERS = ("masks", "results", "uploads")  # the project's own subfolders (uploads: the notebook's uploaded files)
NAME = re.compile(  # every file a project.json may name: exactly the shapes project_format writes
    r"masks/(target|auto|add|erase|first)-[0-9-]{1,40}-[0-9a-f]{16}\.png|results/shadow-k[0-9]{1,9}-[0-9a-f]{16}\.png"
    r"|show-[0-9a-f]{16}\.json"
)


def check_name(folder: Path, name: Any) -> Path:
    """``folder / name`` for a file name from ``project.json``; a ProjectError for any other shape of name."""
    if not isinstance(name, str) or not NAME.fullmatch(name):
        raise ProjectError(
            f"{Path(folder) / 'project.json'} names a file outside the project's own files ({name!r}): the project "
            "was edited by hand or is not safe to open"
        )
    return Path(folder) / name


def check_subfolders(folder: Path) -> None:
    """A ProjectError when ``masks/`` or ``results/`` (or ``project.json``) is a symbolic link or not a folder."""
    for sub in SUBFOLDERS:
        path = Path(folder) / sub
        if path.is_symlink():
            raise ProjectError(
                f"{path} is a symbolic link; a project's {sub}/ must be a real folder inside it (a save would write "
                f"into, and delete from, the folder it points to). Replace it with a copy of that folder"
            )
        if path.exists() and not path.is_dir():
            raise ProjectError(f"{path} is not a folder; the project folder is damaged")
    doc = Path(folder) / "project.json"
    if doc.is_symlink():
        raise ProjectError(f"{doc} is a symbolic link; a project file must be a regular file inside the project")


def regular_file(path: Path) -> bool:
    """Whether ``path`` is a regular file itself (a symbolic link is not, whatever it points to)."""
    try:
        return stat.S_ISREG(os.lstat(path).st_mode)
    except OSError:
        return False


def check_source_path(path: Path, given: Any = None) -> Path:
    """``path`` when it is a regular file or a folder (links followed); a ProjectError for a device, a FIFO or a
    socket, and for a path that does not exist."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        raise ProjectError(f"source not found: {given if given is not None else path}") from None
    except OSError as e:
        raise ProjectError(f"source cannot be read ({e.strerror}): {given if given is not None else path}") from None
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise ProjectError(
            f"source is not a file or a folder (a device, pipe or socket): {given if given is not None else path}; "
            "give a still, a video file or a folder of frames"
        )
    return path


def is_source_path(path: Path) -> bool:
    """Whether ``path`` exists as a regular file or a folder (links followed)."""
    try:
        mode = os.stat(path).st_mode
    except OSError:
        return False
    return stat.S_ISREG(mode) or stat.S_ISDIR(mode)


def check_new_folder(path: Path) -> None:
    """A ProjectError unless ``path`` does not exist yet or is an empty folder (a project is never made over files
    that are not a project's: they are somebody's data)."""
    if not path.exists() and not path.is_symlink():
        return
    if not path.is_dir():
        raise ProjectError(f"{path} exists and is not a folder; choose another name for the project")
    if (path / "project.json").exists():
        raise ProjectError(f"a project already exists at {path}: open it, or choose another name")
    if any(path.iterdir()):
        raise ProjectError(
            f"{path} is a folder with files in it but not a project; choose another name (or empty that folder). "
            "Nothing was changed"
        )
