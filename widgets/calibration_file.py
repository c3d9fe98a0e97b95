"""The studio's calibration: one file for every panel that drives or measures the hand (DESIGN §5.14).

The Rig panel saves the measured rig (and the mount roll) to it; Jog, Export (its play, ramp-in and limits lines),
real-vs-sim and Live read it, so a show is refused on a rig calibrated at another roll in the notebook exactly as
``play --calibration`` refuses it. It is ``state.extras["calibration_path"]`` when set (the Rig panel sets it when it
saves elsewhere), else ``calibration.yaml`` in the project's folder; when that file does not exist the shipped
calibration (``assets/calibration.yaml``) is the studio's. A file that cannot be read stops what would drive the servos
(connect, play, live: one line that says why) and, where a panel only draws, is said in one line while the shipped
calibration is drawn.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from hardware.calibration import Calibration, load_calibration
from studio.errors import StudioError
from studio.sim.hand import Hand
from widgets.state import StudioState

log = logging.getLogger(__name__)


def calibration_path(state: StudioState) -> Path:
    """The studio's calibration file: ``state.extras["calibration_path"]``, else the project folder's one."""
    return Path(state.extras.get("calibration_path") or state.project.path / "calibration.yaml")


def studio_calibration(
    state: StudioState, hand: Hand, say: Callable[[str], None] | None = None, strict: bool = False
) -> Calibration:
    """The studio's calibration (module doc): its file when there is one, else the shipped one. A file that cannot be
    read raises its error when ``strict`` (what drives the servos: never another calibration than the artist's);
    else it is told to ``say`` (one line) and the shipped calibration is used (what only draws)."""
    path = calibration_path(state)
    try:
        return load_calibration(path if path.is_file() else None, hand)
    except StudioError as e:
        if strict:
            raise type(e)(f"{e}: fix it, or move it away to use the shipped calibration") from None
        log.debug("the studio's calibration %s cannot be read: %s", path, e)
        if say is not None:
            say(f"{e}: using the shipped calibration")
        return load_calibration(None, hand)
