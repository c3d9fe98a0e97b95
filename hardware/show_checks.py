"""May this show play here? A show planned for another hand model, or for a mount rolled otherwise than the rig's
calibration records, is refused with one clear line before any servo moves (DESIGN §1, §5.13). The player (`play`),
the dry run, live control (`live`, the Live panel's view) and the real-vs-sim panel all ask these checks.

Will it play as planned? The studio poses the hand within the URDF's limits; a calibration's soft limits may lie
inside them (the shipped one: 0.05 rad inside), and the player stops every command at those. :func:`beyond_soft_limits`
says, before anything moves, which joints a show asks beyond them and by how much (`play`, the demo, the Export
panel), so a shadow that differs from the planned one is never a surprise."""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from hardware.calibration import Calibration
from hardware.errors import MountMismatch, ShowForAnotherHand
from studio.sim.hand import Hand
from studio.sim.roll import mount_text, wrap_deg

log = logging.getLogger(__name__)

__all__ = [
    "MOUNT_TOL_DEG",
    "beyond_names",
    "beyond_soft_limits",
    "calibrated_roll_conflict",
    "check_mount",
    "check_show_hand",
    "soft_limit_summary",
    "soft_limit_text",
]

MOUNT_TOL_DEG = 0.5  # a show's roll and the calibration's may differ by this much, degrees


def calibrated_roll_conflict(roll: float, cal: Calibration) -> float | None:
    """The mount rule every face asks: the roll ``cal`` records, degrees in (-180, 180], when it differs from
    ``roll`` rad by more than ``MOUNT_TOL_DEG``; None when they agree or the calibration records no roll."""
    if cal.roll is None:
        return None
    have = wrap_deg(math.degrees(cal.roll))
    return have if abs(wrap_deg(math.degrees(roll) - have)) > MOUNT_TOL_DEG else None


def check_mount(show_roll: float, cal: Calibration, path: str | Path | None = None, what: str = "show") -> None:
    """Raise :class:`MountMismatch` when ``cal`` records a mount roll other than ``show_roll`` rad (beyond
    ``MOUNT_TOL_DEG``); a calibration that records none accepts every show. ``what`` wants the roll, in the
    message ("show", "live session")."""
    have = calibrated_roll_conflict(show_roll, cal)
    if have is not None:
        want = wrap_deg(math.degrees(show_roll))
        where = f" ({path})" if path else ""
        raise MountMismatch(
            f"this {what} wants the hand mounted at roll {want:+.1f}° but the calibration{where} records the rig at "
            f"{have:+.1f}°: {mount_text(show_roll)}, then record that roll in the calibration"
        )


def check_show_hand(show_hash: str, hand: Hand, path: str | Path | None = None, force: bool = False) -> None:
    """Raise :class:`ShowForAnotherHand` when a show was planned for another hand model (URDF hash ``show_hash``)
    than ``hand``: its angles were checked against another hand's limits and speeds. ``force`` plays it anyway
    (logged as a warning)."""
    if show_hash == hand.hash:
        return
    where = f" {path}" if path else ""
    if force:
        log.warning("playing the show%s planned for hand %s on hand %s (forced)", where, show_hash, hand.hash)
        return
    raise ShowForAnotherHand(
        f"the show{where} was planned for another hand model (hand {show_hash}, this one is {hand.hash}): plan it "
        "again for this hand, or force it if you are sure the two hands move alike"
    )


def beyond_soft_limits(
    positions: np.ndarray, joint_names: Sequence[str], cal: Calibration, tol: float = 1e-6
) -> list[tuple[str, float]]:
    """The joints whose angles in ``positions (N, J) rad`` (columns named by ``joint_names``) lie beyond ``cal``'s
    soft limits by more than ``tol`` rad, as ``(joint name, the most rad beyond)``, farthest first; the player
    stops those joints at the limits. Joints the calibration does not map are left out."""
    q = np.asarray(positions, dtype=np.float64)
    out = []
    for k, name in enumerate(cal.joint_names):
        if name in joint_names:
            col = q[:, list(joint_names).index(name)]
            over = max(float(np.max(cal.lower[k] - col)), float(np.max(col - cal.upper[k])), 0.0)
            if over > tol:
                out.append((name, over))
    return sorted(out, key=lambda x: -x[1])


def beyond_names(beyond: Sequence[tuple[str, float]], most: int = 4) -> str:
    """``"ring_pip by 2.9°, wrist by 1.7° and 2 more"``: the ``most`` farthest of :func:`beyond_soft_limits`'
    answer named, the rest counted."""
    named = ", ".join(f"{n} by {math.degrees(r):.1f}°" for n, r in beyond[:most])
    return named + (f" and {len(beyond) - most} more" if len(beyond) > most else "")


def soft_limit_text(beyond: Sequence[tuple[str, float]], most: int = 4) -> str | None:
    """One line for :func:`beyond_soft_limits`' answer, the ``most`` farthest joints named (None: nothing beyond)."""
    if not beyond:
        return None
    named = beyond_names(beyond, most)
    joints = "1 joint" if len(beyond) == 1 else f"{len(beyond)} joints"
    return (
        f"the show asks {joints} beyond the calibration's soft limits ({named}): the hand stops them at the limits, "
        "so its shadow differs from the planned one"
    )


def soft_limit_summary(positions: np.ndarray, joint_names: Sequence[str], cal: Calibration) -> str:
    """What `show-info` and the Export panel say of the soft limits: :func:`soft_limit_text` of the joints beyond
    them, else that every pose lies within them."""
    text = soft_limit_text(beyond_soft_limits(positions, joint_names, cal))
    return text or "every pose within the calibration's soft limits: the hand plays it as planned"
