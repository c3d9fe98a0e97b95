"""The files the studio ships (installed as ``studio.assets``): the hand URDF, calibration, models, samples.

Every shipped file is found through :func:`asset`, which asks ``importlib.resources`` for this package, so the
same lookup serves a checkout, an editable install and a wheel in site-packages.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path


def asset(relative: str, must_exist: bool = True) -> Path:
    """The installed path of a shipped file, e.g. ``asset("models/selfmodel_cpu128.pt")``.

    Raises ``FileNotFoundError`` naming the file when the installation lacks it (a wheel built without it);
    ``must_exist=False`` returns the path anyway, for a file whose loader reports its absence itself.
    """
    root = resources.files(__name__)
    path = Path(str(root.joinpath(relative)))
    if must_exist and not path.exists():
        raise FileNotFoundError(f"shipped asset missing from the installation: {relative} (looked in {root})")
    return path


def shipped_samples() -> dict[str, Path]:
    """The shipped stills and videos (``targets/``, ``videos/``; the Targets panel's samples): file name → path."""
    found: dict[str, Path] = {}
    for folder in (asset("targets"), asset("videos")):
        for p in sorted(folder.iterdir()):
            if p.suffix.lower() in (".jpeg", ".jpg", ".png", ".gif", ".mp4", ".avi", ".mov"):
                found[p.name] = p
    return found
