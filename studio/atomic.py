"""The one atomic file writer (DESIGN §5.12): a file on disk is always either its old content or its new one.

Every writer goes the same way: write a temporary file in the target's folder, flush, ``fsync``, ``os.replace`` it
onto the target, then ``fsync`` the folder (where the OS allows it) so the rename itself survives a power cut. On any
error (or a ``KeyboardInterrupt``) the temporary file is removed and the old file is left untouched. The temporary
file is created with the usual permissions (``0o666`` less the umask), or the replaced file's own permissions.

Forms: :func:`write_text`, :func:`write_bytes`, :func:`write_json`, :func:`write_with` that hands a binary file
object to a callback (``torch.save``, ``np.savez``, ``PIL.Image.save``...), and :func:`write_via` that hands a path
in a private temporary folder to writers that take a path (``cv2.VideoWriter``).

Temporary names are random and made exclusively (``O_EXCL``, ``O_NOFOLLOW``): a file or symlink planted beside the
target is never written through. They fit the file system's name limit however long the target's name is, and an
``OSError`` (a full disk, a name too long) names the target, not the temporary file.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import shutil
import stat
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

TEMP_EXTRA = len(".") + len(".XXXXXXXX") + len(".tmp")  # bytes a temporary name adds to the target's


def name_max(folder: str | os.PathLike) -> int:
    """The longest file name, in bytes, that the file system holding ``folder`` allows (255 where it cannot say)."""
    try:
        return int(os.pathconf(folder, "PC_NAME_MAX"))
    except (OSError, ValueError, AttributeError):  # Windows has no pathconf
        return 255


def temp_name(path: Path, token: str) -> str:
    """``.NAME.TOKEN.tmp`` beside ``path``, ``NAME`` cut (whole characters) so the name fits the file system's limit:
    a target of 241–255 bytes gets a temporary name too (the folder scan of left-overs matches ``.*.tmp``)."""
    stem, room = path.name, name_max(path.parent) - TEMP_EXTRA
    while len(os.fsencode(stem)) > room:
        stem = stem[:-1]
    return f".{stem}.{token}.tmp"


def _open_temp(path: Path) -> tuple[int, Path]:
    """A new, empty temporary file next to ``path`` (``.NAME.XXXXXXXX.tmp``, created exclusively: never an existing
    file or a symlink planted at that name): its descriptor and path."""
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_BINARY", 0)
    for _ in range(100):
        tmp = path.with_name(temp_name(path, secrets.token_hex(4)))
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"could not create a temporary file next to {path}")


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable; a no-op where folders cannot be opened (Windows)."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_with(path: str | Path, write: Callable[[IO[bytes]], Any]) -> Path:
    """Atomically replace ``path`` with what ``write(f)`` writes into the binary file object ``f``.

    The folder is created if needed. Returns ``path``. Whatever ``write`` raises propagates, with the old file (if
    any) intact and no temporary file left behind.
    """
    path = Path(path)
    temps: list[Path] = []
    with _naming(path, temps):
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = _open_temp(path)
        temps.append(tmp)
        try:
            with os.fdopen(fd, "wb") as f:
                if path.exists():
                    os.chmod(tmp, stat.S_IMODE(path.stat().st_mode))
                write(f)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
    _fsync_dir(path.parent)
    return path


def write_via(path: str | Path, write: Callable[[Path], Any]) -> Path:
    """Atomically replace ``path`` with the file ``write(tmp)`` makes at the path ``tmp``, for writers that take a
    path, not a file object (``cv2.VideoWriter`` picks the container by the name's suffix).

    ``tmp`` (the target's own suffix) lies in a private folder ``.NAME.XXXXXXXX.tmp`` made beside ``path`` (mode
    0700, created exclusively): nobody else can plant a file or a symlink there for the writer to follow. The folder
    is removed whatever happens; on an error the old file is left untouched."""
    path = Path(path)
    temps: list[Path] = []
    with _naming(path, temps):
        path.parent.mkdir(parents=True, exist_ok=True)
        folder = _make_temp_folder(path)
        tmp = folder / f"out{path.suffix}"
        temps += [folder, tmp]
        try:
            write(tmp)
            fd = os.open(tmp, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
            mode = stat.S_IMODE(path.stat().st_mode) if path.exists() else 0o666 & ~_umask()
            os.chmod(tmp, mode)  # the replaced file's permissions, or the usual ones (not the private folder's)
            os.replace(tmp, path)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    _fsync_dir(path.parent)
    return path


def _make_temp_folder(path: Path) -> Path:
    """A new private folder (0700) beside ``path``: ``.NAME.XXXXXXXX.tmp``."""
    for _ in range(100):
        folder = path.with_name(temp_name(path, secrets.token_hex(4)))
        try:
            folder.mkdir(mode=0o700)
            return folder
        except FileExistsError:
            continue
    raise FileExistsError(f"could not create a temporary folder next to {path}")


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def _naming(path: Path, temps: list[Path]) -> Iterator[None]:
    """An ``OSError`` with no file name, or naming one of the hidden ``temps``, is raised again naming ``path`` (the
    file the caller asked for): a full disk reads ``[Errno 28] No space left on device: 'show.json'``."""
    try:
        yield
    except OSError as e:
        if e.errno is None or (e.filename is not None and str(e.filename) not in {str(t) for t in temps}):
            raise
        raise OSError(e.errno, e.strerror, str(path)) from e


def write_bytes(path: str | Path, data: bytes) -> Path:
    """Atomically replace ``path`` with ``data``."""
    return write_with(path, lambda f: f.write(data))


def write_text(path: str | Path, text: str, encoding: str = "utf-8") -> Path:
    """Atomically replace ``path`` with ``text`` (encoded as given; newlines are written as they are)."""
    return write_bytes(path, text.encode(encoding))


def write_json(path: str | Path, obj: Any, indent: int | None = 2, **dumps: Any) -> Path:
    """Atomically replace ``path`` with ``obj`` as JSON (``json.dumps`` options pass through) and a final newline.

    The document is serialised before the file is touched, so an unserialisable object leaves the old file as it is.
    """
    return write_text(path, json.dumps(obj, indent=indent, **dumps) + "\n")
