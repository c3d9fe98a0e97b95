"""The studio's files: the one atomic writer (DESIGN §5.12), a file on disk always either its old content or its new
one, and the one bounded reader of a JSON file a person gave.

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

Reading (:func:`read_json`) a JSON file a person gave (a show, keyframes, a pose, a project): bounded in size and in
nesting, every failure one clear sentence that names the file (DESIGN §5.8).

Python's JSON reader and the schema validator recurse once per level, so a file nested thousands of levels deep
raised ``RecursionError`` (an "internal error"); no file the studio writes is nested more than a few levels, so
:data:`MAX_DEPTH` is far above any of them and far below the interpreter's limit. The size bound keeps a file from
filling the memory while it is parsed (a JSON document takes several times its size as Python objects).
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

from studio.errors import StudioError

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


# --- reading: a JSON file a person gave ----------------------------------------------------------------------
MAX_DEPTH = 64  # levels of nested arrays and objects (the studio's files use fewer than 10; Python fails near 1000)
MAX_BYTES = 64 * 2**20  # bytes of a JSON file read whole (a keyframes file of 10,000 keyframes is ~10 MB)
TOO_DEEP = f"JSON nested deeper than {MAX_DEPTH} levels (no Shadow Studio file is: is it the right file?)"


class JsonFileError(StudioError):
    """A JSON file cannot be read: too large, not UTF-8 text, not valid JSON, or nested too deeply. ``reason`` is
    the sentence without the path; ``corrupt``: the text is not JSON (truncated?), so writing it again may help."""

    def __init__(self, path: str | Path, reason: str, corrupt: bool = False):
        self.path, self.reason, self.corrupt = str(path), reason, corrupt
        super().__init__(f"{path}: {reason}")


def read_json(path: str | Path, max_bytes: int = MAX_BYTES, what: str = "JSON file") -> Any:
    """The document in the JSON file ``path``. Raises ``FileNotFoundError`` or :class:`JsonFileError`."""
    path = Path(path)
    size = path.stat().st_size
    if size > max_bytes:
        raise JsonFileError(path, f"{size / 2**20:.0f} MB, larger than the {max_bytes // 2**20} MB a {what} may be")
    data = path.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:
        kind = image_kind(data)
        hint = f"it is a {kind} image, not a {what}" if kind else f"it is not UTF-8 text; a {what} is JSON"
        raise JsonFileError(path, hint) from None
    return parse_json(text, path)


def parse_json(text: str, path: str | Path) -> Any:
    """``json.loads(text)`` with every failure a :class:`JsonFileError` naming ``path``."""
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise JsonFileError(
            path, f"not valid JSON (truncated or corrupt?) at line {e.lineno} column {e.colno}: {e.msg}", corrupt=True
        ) from None
    except RecursionError:  # deeper than the interpreter reads
        raise JsonFileError(path, TOO_DEEP) from None
    if json_depth(doc) > MAX_DEPTH:
        raise JsonFileError(path, TOO_DEEP)
    return doc


def json_depth(doc: Any, stop: int = MAX_DEPTH) -> int:
    """Levels of nested arrays and objects in ``doc`` (0 for a number or a string), counted without recursion and
    given up once past ``stop`` (the result is then ``stop + 1``)."""
    deepest, stack = 0, [(doc, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, dict):
            node = node.values()
        elif not isinstance(node, list):
            continue
        deepest = max(deepest, depth)
        if depth > stop:
            return stop + 1
        stack.extend((child, depth + 1) for child in node if isinstance(child, (dict, list)))
    return deepest


IMAGE_MAGIC = {b"\x89PNG": "PNG", b"\xff\xd8\xff": "JPEG", b"GIF8": "GIF", b"BM": "BMP", b"RIFF": "WebP"}


def image_kind(data: bytes) -> str | None:
    """``"PNG"``, ``"JPEG"``... when ``data`` starts like an image file, else None."""
    return next((kind for magic, kind in IMAGE_MAGIC.items() if data.startswith(magic)), None)
