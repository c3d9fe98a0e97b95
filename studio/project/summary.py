"""A project in plain data, for ``shadow-studio project info`` and the widgets."""

from __future__ import annotations

import math

from studio.project.state import PoseResult, ProjectState
from studio.project.status import ProjectStatus


def _total(result: PoseResult | None) -> float | None:
    total = None if result is None else result.loss.get("total")
    return None if total is None or not math.isfinite(total) else float(total)


def summarise(s: ProjectState, status: ProjectStatus) -> dict:
    """Plain data for ``project info`` and the widgets: sources (missing? changed?), frames, keyframes with
    their result's state ("current", "stale" or "missing"), counts, the show (stale?), undo/redo."""
    missing = {m.index for m in status.missing_sources}
    keyframes = []
    for kf in s.keyframes:
        state = status.result_state(kf.id)
        keyframes.append({
            "id": kf.id, "representative": kf.representative, "members": list(kf.members),
            "time_s": kf.time_s, "hold": kf.hold, "edited": kf.edited, "result": state,
            "loss": _total(s.results.get(kf.id)),
        })  # fmt: skip
    counts = {c: sum(k["result"] == c for k in keyframes) for c in ("current", "stale", "missing")}
    show = None
    if s.show is not None:
        show = {"duration_s": s.show.duration, "samples": len(s.show.times), "stale": status.show_stale}
    return {
        "project": status.path,
        "title": s.title,
        "sources": [
            {
                "path": src.path,
                "absolute": src.absolute,
                "kind": src.kind,
                "footage": src.footage,
                "missing": i in missing,
                "changed": i in status.changed_sources,
                "frames": sum(f.source == i for f in s.frames),
            }
            for i, src in enumerate(s.sources)
        ],
        "frames": len(s.frames),
        "size": s.video.size,
        "hz": s.video.hz,
        "tau": s.clustering.tau,
        "keyframes": keyframes,
        "results": counts,
        "painted_frames": sorted(set(s.additions) | set(s.erasures)),
        "show": show,
        "can_undo": status.can_undo,
        "can_redo": status.can_redo,
    }
