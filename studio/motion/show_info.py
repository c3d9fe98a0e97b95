"""A show described in a few lines of text: what ``shadow-studio show-info`` prints and the export panel shows."""

from __future__ import annotations

import numpy as np

from studio.errors import count
from studio.motion.show import Show
from studio.sim.roll import mount_text


def keyframe_text(show: Show, keyframes: int | None = None) -> str:
    """The keyframes as the artist made them (``keyframes``: the project's count; else the distinct targets the
    show's marks name, or the marks), then the times the show reaches them: a held still, or a keyframe a video
    reaches again, has more than one mark."""
    marks = show.keyframes
    n = keyframes if keyframes is not None else len({m.target for m in marks if m.target}) or len(marks)
    times = ", ".join(f"{m.t:.2f} s" + (" (hold)" if m.hold else "") for m in marks[:12])
    times += ", …" if len(marks) > 12 else ""
    if len(marks) != n:
        return f"{count(n, 'keyframe')} at {count(len(marks), 'mark')} on the show clock: {times}"
    return f"{count(n, 'keyframe')}, on the show clock at {times}"


def show_info_lines(show: Show) -> list[str]:
    """Title, format, hand, calibration, how to mount the hand (its roll), duration and samples, keyframe times,
    media, the peak joint speed as a share of its velocity limit, and the late segments the planner stretched, one
    line each."""
    media = f"{show.media.kind} {show.media.path} (offset {show.media.offset_s:+.3f} s)" if show.media else "-"
    speed = np.abs(np.diff(show.positions, axis=0)) / np.diff(show.times)[:, None] if len(show.times) > 1 else None
    lines = [
        f"title:        {show.title}",
        f"format:       version {show.format_version}, created {show.created}",
        f"hand:         {show.hand_hash} ({len(show.joint_names)} joints)",
        f"calibration:  {show.calibration or '-'}",
        f"mount:        {mount_text(show.roll)}",
        f"duration:     {show.duration:.3f} s, {len(show.times)} samples at {show.rate_hz:g} Hz",
        f"keyframes:    {keyframe_text(show)}",
        f"media:        {media}",
    ]
    if speed is not None:
        j = int(np.argmax((speed / show.limits.velocity).max(axis=0)))
        ratio = speed[:, j].max() / show.limits.velocity[j]
        lines.append(f"peak speed:   {show.joint_names[j]} at {ratio:.0%} of its velocity limit")
    late = show.provenance.get("late_segments") or []
    lines.append(f"late:         {count(len(late), 'segment')} stretched" if late else "late:         none")
    return lines
