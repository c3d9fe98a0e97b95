"""The e-stop latch that outlives a process: one small file that every process of the studio reads.

:meth:`hardware.bus.ServoBus.estop` writes it (through the one atomic writer),
:meth:`~hardware.bus.ServoBus.reset_estop` removes it, and every bus refuses motion while it exists, so an e-stop set
by ``jog``, a player, the notebook's Jog panel or ``shadow-studio estop`` holds in every process, whichever set it,
until an explicit reset (``shadow-studio estop --reset``, ``reset`` in ``jog``, the Jog panel's reset button). A
process that is open on the servos when the file appears halts them within a tick
(:class:`hardware.session.ServoSession` watches the file).

Where: ``$SHADOW_STUDIO_ESTOP`` (a file path), else ``estop.json`` in the studio's home folder
(:func:`studio.home.studio_home`: ``$SHADOW_STUDIO_HOME``, else ``~/.cache/shadow-studio``). Processes that see
another home (another user, another ``$SHADOW_STUDIO_HOME``) do not share it.

One latch for every port: an e-stop stops the hand on any serial port and the emulator alike. That is the simplest
rule that cannot leave a hand moving because its port was named differently (``/dev/ttyUSB0`` and
``/dev/serial/by-id/…`` are one adapter; the emulator's pty changes every run). Failing safe: a file that exists but
cannot be read or parsed still counts as latched; only a reset removes it.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from hardware.errors import EStopLatched
from studio.atomic import write_json

ESTOP_ENV = "SHADOW_STUDIO_ESTOP"  # environment variable: the e-stop latch file (tests point it into a tmp folder)
FILE_NAME = "estop.json"  # the latch file's name in the studio's home folder


@dataclass(frozen=True)
class Latch:
    """A latched e-stop as its file records it."""

    at: str  # when it was set (ISO 8601, local time with its offset)
    by: str  # what set it, e.g. "jog on servo bus '/dev/ttyUSB0'"
    pid: int  # the process that set it (0: not recorded)

    def describe(self) -> str:
        """``set by … (process N) at …``."""
        who = f"{self.by} (process {self.pid})" if self.pid else self.by
        return f"set by {who} at {self.at}"


def latch_path() -> Path:
    """The latch file: ``$SHADOW_STUDIO_ESTOP``, else ``estop.json`` in the studio's home folder."""
    from studio.home import studio_home

    env = os.environ.get(ESTOP_ENV)
    return Path(env).expanduser() if env else studio_home() / FILE_NAME


def is_latched(path: str | Path | None = None) -> bool:
    """Whether the latch file exists (one ``stat``: cheap enough to ask before every motion command). A file that
    cannot even be looked at (no permission on its folder) counts as latched."""
    try:
        os.stat(path or latch_path())
    except (FileNotFoundError, NotADirectoryError):
        return False
    except OSError:
        return True
    return True


def read_latch(path: str | Path | None = None) -> Latch | None:
    """The latch recorded in the file, or None when there is none. A file that cannot be read or parsed is still a
    latch (its ``by`` says so)."""
    path = Path(path or latch_path())
    try:
        text = path.read_text(encoding="utf-8")
    except (FileNotFoundError, NotADirectoryError):
        return None
    except OSError as e:
        return Latch("an unknown time", f"an unreadable latch file {path} ({e.strerror or e})", 0)
    try:
        doc = json.loads(text)
        return Latch(str(doc["at"]), str(doc["by"]), int(doc.get("pid", 0)))
    except (ValueError, TypeError, KeyError):
        return Latch("an unknown time", f"a damaged latch file {path}", 0)


def set_latch(by: str, path: str | Path | None = None) -> Latch:
    """Latch the e-stop for every process (atomically); a latch already set is kept as it is (it says what stopped
    the hand first). Returns the latch in force. Raises ``OSError`` when the file cannot be written."""
    path = Path(path or latch_path())
    held = read_latch(path)
    if held is not None:
        return held
    latch = Latch(datetime.now().astimezone().isoformat(timespec="seconds"), by, os.getpid())
    write_json(path, {"at": latch.at, "by": latch.by, "pid": latch.pid})
    return latch


def clear_latch(path: str | Path | None = None) -> Latch | None:
    """Reset the e-stop for every process: remove the file. Returns the latch that was cleared (None: none was
    set). Raises ``OSError`` when the file exists but cannot be removed."""
    path = Path(path or latch_path())
    held = read_latch(path)
    try:
        path.unlink()
    except (FileNotFoundError, NotADirectoryError):
        pass  # not latched (or reset meanwhile by another process)
    return held


def latched_message(where: str) -> str:
    """One line: the e-stop is latched, by what and when (or, when its file holds none, on ``where``), and that
    nothing moves until a reset (each face adds how it resets)."""
    held = read_latch()
    said = f" ({held.describe()})" if held is not None else f" on {where}"
    return f"the e-stop is latched{said}: no servo moves until it is reset"


def check_not_latched(where: str = "the servos") -> None:
    """Raise :class:`EStopLatched` (:func:`latched_message`) when the latch file is set: a verb asks before it
    opens the servos."""
    if is_latched():
        raise EStopLatched(latched_message(where))
