"""A project in plain data, for ``shadow-studio project info`` and the widgets."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from studio.imitate.transitions import TransitionConfig, transition_success
from studio.project.state import PoseResult, ProjectState
from studio.project.status import ProjectStatus
from studio.sim.hand import load_hand
from studio.sim.roll import mount_text, roll_deg


def _total(result: PoseResult | None) -> float | None:
    total = None if result is None else result.loss.get("total")
    return None if total is None or not math.isfinite(total) else float(total)


def summarise(s: ProjectState, status: ProjectStatus) -> dict:
    """Plain data for ``project info`` and the widgets: sources (missing? changed?), frames, keyframes with
    their result's state ("current", "stale" or "missing"; what a stopped run still owes it, which the next run
    does: ``AWAITS``), counts, the show (stale?), undo/redo."""
    missing = {m.index for m in status.missing_sources}
    keyframes = []
    for kf in s.keyframes:
        state = status.result_state(kf.id)
        keyframes.append({
            "id": kf.id, "representative": kf.representative, "members": list(kf.members),
            "time_s": kf.time_s, "hold": kf.hold, "edited": kf.edited, "result": state,
            "loss": _total(s.results.get(kf.id)),
            "collides": kf.id in s.results and not s.results[kf.id].collision_free,
            "awaits": s.results[kf.id].awaits if kf.id in s.results else "",  # what a stopped run still owes it
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
        "mount": {
            "auto": s.mount.auto,
            "chosen": s.mount.chosen,
            "roll_deg": roll_deg(s.mount.roll),
            "how": mount_text(s.mount.roll) if s.mount.chosen else "roll auto: chosen at the next run",
            "apart": mount_apart(s),
        },
        "keyframes": keyframes,
        "results": counts,
        "colliding": [k["id"] for k in keyframes if k["collides"]],  # results whose pose penetrates itself
        "painted_frames": sorted(set(s.additions) | set(s.erasures)),
        "show": show,
        "can_undo": status.can_undo,
        "can_redo": status.can_redo,
    }


def mount_apart(s: ProjectState) -> list[dict]:
    """The keyframes that the mount's roll (auto's, or the artist's) casts clearly worse than a roll of their own would
    (``Mount.apart``), those still as they were when it was measured: ``{"keyframe", "source", "loss",
    "own_roll_deg", "own_loss"}``."""
    if not s.mount.chosen:
        return []
    now = {kf.id: kf.representative for kf in s.keyframes}
    return [
        {"keyframe": a.keyframe, "source": Path(s.sources[s.frames[a.frame].source].path).name,
         "loss": round(a.loss, 4), "own_roll_deg": roll_deg(a.own_roll), "own_loss": round(a.own_loss, 4)}
        for a in s.mount.apart if now.get(a.keyframe) == a.frame < len(s.frames)
    ]  # fmt: skip


def apart_text(apart: list[dict]) -> str:
    """:func:`mount_apart`'s keyframes in one sentence for the artist ("" when none): where each would read better."""
    if not apart:
        return ""
    if len(apart) == 1:
        a = apart[0]
        return (f"one mount serves the whole show: keyframe {a['keyframe']} ({a['source']}) would cast better at roll "
                f"{a['own_roll_deg']:+.0f}° (first-answer outline loss {a['own_loss']:.3f} there, {a['loss']:.3f} on "
                "this mount); set another roll by hand, or give it a show of its own")  # fmt: skip
    each = "; ".join(f"{a['keyframe']} ({a['source']}) at {a['own_roll_deg']:+.0f}° ({a['own_loss']:.3f}, "
                     f"{a['loss']:.3f})" for a in apart)  # fmt: skip
    return ("one mount serves the whole show: these keyframes would cast better on a roll of their own (first-answer "
            f"outline loss there, then on this mount): {each}; set another roll by hand, or give them a show of "
            "their own")  # fmt: skip


def project_transitions(s: ProjectState, cfg: TransitionConfig | None = None) -> dict:
    """Transition success between consecutive keyframes of each source (first-appearance order), summed over the
    sources: ``{"success", "transitions", "rate"}`` (rate None with no transition). Endpoint totals as ``cfg.total``
    reads them from each result's evaluation (its losses where it has none)."""
    cfg = cfg or TransitionConfig()
    names = load_hand().joint_names
    ok = n = 0
    for i in range(len(s.sources)):
        ids = [kf.id for kf in s.keyframes if s.frames[kf.representative].source == i and kf.id in s.results]
        if len(ids) < 2:
            continue
        results = [s.results[k] for k in ids]
        parts = {"base": ("base",), "image": ("base", "expr"), "full": ("base", "expr", "temporal")}[cfg.total]
        totals = []
        for r in results:
            e = r.evaluation or r.loss
            vals = [e.get(p, math.nan) for p in parts]
            totals.append(vals[0] + sum(0.0 if math.isnan(v) else v for v in vals[1:]))
        good, _ = transition_success(np.stack([r.theta(names) for r in results]), np.array(totals), cfg)
        ok, n = ok + int(good.sum()), n + len(good)
    return {"success": ok, "transitions": n, "rate": (ok / n) if n else None}
