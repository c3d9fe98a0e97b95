"""Where ``play`` and ``jog`` keep their logs: ``--log PATH``, else ``<studio home>/logs/<verb>-<local time>.<ext>``
(:func:`studio.home.studio_home`: ``$SHADOW_STUDIO_HOME``, else ``~/.cache/shadow-studio``), written however the
verb ends (DESIGN §5.13) and through the one atomic writer."""

from __future__ import annotations

import sys
from collections.abc import Callable
from datetime import datetime
from pathlib import Path


def log_path(given: Path | None, kind: str, suffix: str) -> Path:
    """``--log`` as given, else ``<studio home>/logs/<kind>-<local time><suffix>``."""
    if given is not None:
        return Path(given)
    from studio.home import studio_home

    return studio_home() / "logs" / f"{kind}-{datetime.now().strftime('%Y%m%d-%H%M%S')}{suffix}"


def save_log(write: Callable[[Path], object], path: Path, given: Path | None, what: str) -> None:
    """``write(path)``, then say where (stdout); a log the user did not ask for (``given`` None: the default place)
    that cannot be written is one line on stderr, not a failed verb."""
    try:
        write(path)
    except OSError as e:
        if given is not None:
            raise
        print(f"could not save the {what} log to {path}: {e}", file=sys.stderr)
        return
    print(f"{what} saved to {path}")
