"""The one atomic file writer (DESIGN §5.12): a file on disk is always either its old content or its new one.

Every writer goes the same way: write a temporary file in the target's folder, flush, ``fsync``, ``os.replace`` it
onto the target, then ``fsync`` the folder (where the OS allows it) so the rename itself survives a power cut. On any
error (or a ``KeyboardInterrupt``) the temporary file is removed and the old file is left untouched. The temporary
file is created with the usual permissions (``0o666`` less the umask), or the replaced file's own permissions.

Forms: :func:`write_text`, :func:`write_bytes`, :func:`write_json`, and :func:`write_with` that hands a binary file
object to a callback (``torch.save``, ``np.savez``, ``PIL.Image.save``...).
"""

from __future__ import annotations

import json
import os
import secrets
import stat
from collections.abc import Callable
from pathlib import Path
from typing import IO, Any


def _open_temp(path: Path) -> tuple[int, Path]:
    """A new, empty temporary file next to ``path`` (``.NAME.XXXXXXXX.tmp``): its descriptor and path."""
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{secrets.token_hex(4)}.tmp")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666), tmp
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
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = _open_temp(path)
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
