"""Where the studio keeps the user's things: the user folder (demo project, the lab's notebook) and the cache.

``$SHADOW_STUDIO_HOME`` moves the user folder and ``$SHADOW_STUDIO_CACHE`` the cache (built indexes, reusable by
every project and process); both default to ``~/.cache/shadow-studio``.
"""

from __future__ import annotations

import os
from pathlib import Path

HOME_ENV = "SHADOW_STUDIO_HOME"  # environment variable: the user folder for the demo project and the lab's notebook
CACHE_ENV = "SHADOW_STUDIO_CACHE"  # environment variable: the folder of rebuildable caches (retrieval indexes)
DEFAULT = Path("~/.cache/shadow-studio")


def studio_home() -> Path:
    """The user folder of the studio: ``$SHADOW_STUDIO_HOME``, else ``~/.cache/shadow-studio``."""
    return Path(os.environ.get(HOME_ENV) or DEFAULT).expanduser()


def cache_dir() -> Path:
    """The folder of rebuildable caches: ``$SHADOW_STUDIO_CACHE``, else ``~/.cache/shadow-studio``."""
    return Path(os.environ.get(CACHE_ENV) or DEFAULT).expanduser()
