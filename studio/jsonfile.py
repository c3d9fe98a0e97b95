"""Reading a JSON file a person gave (a show, keyframes, a pose, a project): bounded in size and in nesting, every
failure one clear sentence that names the file (DESIGN §5.8).

Python's JSON reader and the schema validator recurse once per level, so a file nested thousands of levels deep
raised ``RecursionError`` (an "internal error"); no file the studio writes is nested more than a few levels, so
:data:`MAX_DEPTH` is far above any of them and far below the interpreter's limit. The size bound keeps a file from
filling the memory while it is parsed (a JSON document takes several times its size as Python objects).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from studio.errors import StudioError

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
