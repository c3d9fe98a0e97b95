"""What the operating system can say that a person must read as one line, not as an "internal error": a full disk,
a name too long, a read-only folder... (``main`` maps them; DESIGN §5.8). An ``OSError`` with another errno is a bug
and stays an internal error."""

from __future__ import annotations

import errno

from studio.targets.path_checks import shown

HINTS = {  # errno → what to do about it
    errno.ENOSPC: "free some space or write elsewhere",
    errno.EDQUOT: "free some space or write elsewhere",
    errno.EFBIG: "the file system takes no file this large: write elsewhere",
    errno.ENAMETOOLONG: "choose a shorter name",
    errno.EROFS: "write elsewhere",
    errno.ENOTDIR: "a part of the path is a file, not a folder",
    errno.EEXIST: "move it away or choose another name",
    errno.ELOOP: "the path has a symbolic link loop",
    errno.EIO: "the disk or the network share failed: check it",
    errno.EMFILE: "close other programs or raise the limit (ulimit -n)",
    errno.ENFILE: "close other programs",
    errno.ENOTEMPTY: "move its content away first",
    errno.EBUSY: "another program holds it: close that program",
}


def os_error_line(error: OSError) -> str | None:
    """``"show.json: No space left on device (free some space or write elsewhere)"`` for an error a person can meet
    (:data:`HINTS`); None for any other."""
    hint = HINTS.get(error.errno) if error.errno is not None else None
    if hint is None:
        return None
    where = f"{shown(error.filename)}: " if error.filename is not None else ""
    return f"{where}{error.strerror or 'failed'} ({hint})"
