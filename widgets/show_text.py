"""What the Export panel says about a show, in the artist's terms.

It starts from what ``shadow-studio show-info`` prints (:func:`studio.motion.show_info.show_info_lines`) and says
three things differently: the **keyframes** are counted as the project holds them (show-info counts the distinct
targets the show's marks name: the same unless the file lacks them), **media** is what the show plays beside or,
when nothing, the sources it was made from, and the **late** transitions are listed (frames, keyframes, needed
versus given seconds). It adds the
**ramp-in**: before show time 0 the player brings the hand from where it stands to the show's first pose, as
:meth:`hardware.player.Player.trajectory` computes it, so a 1.44 s show can take seconds more to play; and the
**limits**: the joints the show asks beyond the calibration's soft limits, where the player stops them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hardware.calibration import Calibration
from hardware.constants import CENTER_UNITS
from hardware.player import Player, PlayerConfig
from hardware.show_checks import soft_limit_summary
from studio.errors import count
from studio.motion.show import Show
from studio.motion.show_info import keyframe_text, show_info_lines
from widgets.words import late_lines, seconds

LABEL = 14  # width of a line's label, as show-info prints them ("keyframes:    ")


@dataclass(frozen=True)
class ProjectView:
    """What the panel knows of the project a show was planned from (None fields: a show file read on its own)."""

    keyframes: int | None = None  # the project's keyframe count
    sources: tuple[str, ...] = ()  # the names of its sources, in order
    late: list[dict] | None = None  # its late transitions (VideoTiming.late_transitions); None: not known


def _line(label: str, text: str) -> str:
    return f"{label + ':':<{LABEL}}{text}"


def keyframe_line(show: Show, keyframes: int | None) -> str:
    """The keyframes as the artist made them (the project's ``keyframes``), then the times the show reaches them."""
    return _line("keyframes", keyframe_text(show, keyframes))


def media_line(show: Show, sources: tuple[str, ...]) -> str | None:
    """What plays beside the show, else what it was made from (None: nothing to say)."""
    if show.media is not None:
        name = Path(show.media.path).name
        return _line("media", f"{name} ({show.media.kind}) plays beside it from {seconds(show.media.offset_s)}")
    if sources:
        return _line("made from", ", ".join(sources))
    return None


def late_text(show: Show, late: list[dict] | None) -> list[str]:
    """The transitions the planner stretched: one line each, by frame when the project's timing says which."""
    if late is None:  # a show file on its own: its planner's segments, by show time
        segments = show.provenance.get("late_segments") or []
        rows = [f"{seconds(g['t_start'])}–{seconds(g['t_end'])}: needs {seconds(g['feasible'])}, given "
                f"{seconds(g['t_end'] - g['t_start'])}" for g in segments]  # fmt: skip
    else:
        rows = late_lines(late)
    if not rows:
        return [_line("late", "none (every move fits the servos)")]
    head = _line("late", f"{count(len(rows), 'transition')} too fast for the servos, stretched (later ones shift):")
    return [head, *(" " * LABEL + r for r in rows)]


def ramp_in_s(show: Show, calibration: Calibration, start: np.ndarray, player: PlayerConfig | None = None) -> float:
    """Seconds the player ramps from ``start (J,)`` rad (calibration order) to the show's first pose before show time 0
    (the player's own computation, :meth:`~hardware.player.Player.trajectory`)."""
    cfg = player or PlayerConfig()
    planner = Player(None, calibration, cfg)  # type: ignore[arg-type]  # trajectory() never touches the bus
    _, ticks = planner.trajectory(show.times, show.positions, show.joint_names, start)
    return ticks / cfg.rate_hz


def ramp_line(show: Show, calibration: Calibration, on_emulator: bool, player: PlayerConfig | None = None) -> str:
    """The ramp-in before the show starts: from the emulator's start pose (its servos at mid travel), or at most from
    the farthest pose within the calibration's limits (a hand at a port stands wherever it was left)."""
    if on_emulator:
        start = calibration.to_rad(np.full(len(calibration.ids), float(CENTER_UNITS)))
        where = "the emulator's start pose"
    else:
        first = np.array([show.positions[0][show.joint_names.index(n)] for n in calibration.joint_names])
        lo, hi = calibration.lower, calibration.upper
        start = np.where(np.abs(first - lo) > np.abs(hi - first), lo, hi)  # the farthest pose: the longest ramp
        where = "where the hand stands (at most)"
    t = ramp_in_s(show, calibration, start, player)
    total = t + show.duration
    return _line("ramp-in", f"{seconds(t)} from {where} to the first pose before the show starts: playing takes "
                            f"about {seconds(total)}")  # fmt: skip


def limits_line(show: Show, calibration: Calibration) -> str:
    """Whether the show's poses lie within the calibration's soft limits, where the player stops every command
    (:func:`hardware.show_checks.beyond_soft_limits`)."""
    return _line("limits", soft_limit_summary(show.positions, show.joint_names, calibration))


def artist_lines(show: Show, view: ProjectView, hand: Sequence[str] = ()) -> list[str]:
    """Every line of the panel's description of ``show`` (module doc), then the ``hand`` lines (where it plays)."""
    out: list[str] = []
    for line in show_info_lines(show):
        label = line.split(":", 1)[0]
        if label == "keyframes":
            out.append(keyframe_line(show, view.keyframes))
        elif label == "media":
            media = media_line(show, view.sources)
            out += [media] if media else []
        elif label == "late":
            out += late_text(show, view.late)
        else:
            out.append(line)
    return out + list(hand)
