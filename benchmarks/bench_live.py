"""Live on this machine: a video file as the camera, the servo emulator as the hand, ``shadow-studio live``'s engine.

For each camera (default: the shared DAVIS bear masks, a frame folder at 24 fps, and the bear MP4, both looped for
``--seconds``) it runs :func:`studio.project.live.run_live` on the emulator (real pyserial over a pseudo-terminal)
and measures:

- **latency** from a camera frame's arrival to the first servo command that carries its pose (p50 / p99, ms), and
  the **updates** (poses handed to the motion) per second;
- **loss gap**: the mean loss of the commanded poses against their frames' targets minus the mean loss of the
  offline first answer on the same targets (the retrieval's best pose over its full shortlist, no temporal term:
  :func:`studio.imitate.live_pose.offline_first_answer`, the reference path, computed after the session);
- **collisions**: ticks whose commanded pose collides (the collision world, every tick);
- **limit violations**: ticks outside the calibration's soft limits, clipped by the player's safety layer, or
  beyond the joints' velocity, acceleration or jerk limits (finite differences of consecutive ticks, 2 % slack).

Prints one line per camera, then, last, one JSON line with ``latency_p50_ms``, ``latency_p99_ms``,
``updates_per_s``, ``loss_gap``, ``collisions`` and ``limit_violations`` over all cameras (and each camera's).

    python benchmarks/bench_live.py [--camera FILE_OR_FOLDER ...] [--seconds 15]
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "targets"
DEFAULT_CAMERAS = (SHARED / "davis" / "bear", SHARED / "video" / "bear-mp4")


def _video_in(path: Path) -> Path:
    """A folder holding one video file → that file (the shared MP4 sits in a folder with its SOURCE text)."""
    if path.is_dir():
        videos = sorted(p for p in path.iterdir() if p.suffix.lower() in (".mp4", ".avi", ".mov", ".mkv", ".webm"))
        if videos:
            return videos[0]
    return path


def limit_violations(sent: np.ndarray, t: np.ndarray, limits, playback, slack: float = 0.02) -> dict[str, int]:
    """Ticks ``sent (T, J)`` rad (calibration order) at ``t (T,)`` s that break each limit (module doc): ``{"position",
    "clipped", "velocity", "acceleration", "jerk", "total"}`` (total: ticks breaking any)."""
    out: dict[str, np.ndarray] = {}
    out["position"] = ((sent < limits.lower - 1e-9) | (sent > limits.upper + 1e-9)).any(axis=1)
    out["clipped"] = np.asarray(playback.clipped_limit).any(axis=1) | np.asarray(playback.clipped_step).any(axis=1)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.025
    gaps = np.abs(np.diff(t) - dt) > dt / 4  # a skipped tick: differences across it are not one tick's
    for order, name, bound in ((1, "velocity", limits.velocity), (2, "acceleration", limits.acceleration),
                               (3, "jerk", limits.jerk)):  # fmt: skip
        bad = np.zeros(len(sent), dtype=bool)
        if len(sent) > order:
            d = np.diff(sent, n=order, axis=0) / dt**order
            across = np.zeros(len(d), dtype=bool)
            for k in range(order):
                across |= gaps[k : k + len(d)]
            bad[order:] = (np.abs(d) > bound * (1 + slack) + 1e-9).any(axis=1) & ~across
        out[name] = bad
    counts = {k: int(v.sum()) for k, v in out.items()}
    counts["total"] = int(np.logical_or.reduce(list(out.values())).sum()) if len(sent) else 0
    return counts


def run_camera(source: Path, seconds: float, imitator, hand, cal) -> dict:
    """One live session with ``source`` as the camera → its figures."""
    from hardware.session import ServoSession
    from studio.imitate.live_pose import offline_first_answer
    from studio.motion.limits import JointLimits
    from studio.project.capture import open_camera_source
    from studio.project.live import run_live
    from studio.project.live_config import LiveConfig

    targets: list[tuple[np.ndarray, float]] = []

    def keep(u) -> None:
        if u.theta is not None:
            targets.append((np.array(u.target), float(u.loss)))

    camera = open_camera_source(str(source))
    camera.loop = True
    try:
        with ServoSession(calibration=cal) as session:
            result = run_live(imitator, session.bus, cal, camera, LiveConfig(max_seconds=seconds), on_update=keep)
    finally:
        camera.close()
    pb = result.playback
    order = [hand.joint_names.index(n) for n in cal.joint_names]
    sent = np.asarray(pb.sent)
    theta = np.empty_like(sent)
    theta[:, order] = sent
    collisions = int(imitator.refiner.world.in_collision(theta, check=False).sum()) if len(theta) else 0
    lim = JointLimits.from_hand(hand)
    lim = JointLimits(np.maximum(lim.lower[order], cal.lower), np.minimum(lim.upper[order], cal.upper),
                      lim.velocity[order], lim.acceleration[order], lim.jerk[order])  # fmt: skip
    violations = limit_violations(sent, np.asarray(pb.t), lim, pb)
    offline = np.array([offline_first_answer(imitator.retrieval_index(), imitator.refiner, m) for m, _ in targets])
    live = np.array([loss for _, loss in targets])
    lat = result.latencies_s * 1000
    return {
        "camera": str(source),
        "stopped": pb.reason.value,
        "seconds": round(result.seconds, 2),
        "frames": result.frames,
        "updates": result.updates,
        "updates_per_s": round(result.updates_per_s, 2),
        "latency_p50_ms": round(float(np.percentile(lat, 50)), 1) if len(lat) else None,
        "latency_p99_ms": round(float(np.percentile(lat, 99)), 1) if len(lat) else None,
        "loss_live": round(float(live.mean()), 4) if len(live) else None,
        "loss_offline_first": round(float(offline.mean()), 4) if len(offline) else None,
        "loss_gap": round(float(live.mean() - offline.mean()), 4) if len(live) else None,
        "collisions": collisions,
        "limit_violations": violations["total"],
        "violations": violations,
        "ticks": len(sent),
        "tick_late_p99_ms": round(float(np.percentile(np.abs(pb.lateness_s), 99) * 1000), 2) if len(sent) else None,
        "holds": result.holds,
        "_lat": lat,
        "_gap": (live, offline),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--camera", type=Path, nargs="+", default=None, help="video files or frame folders (default: "
                   "the shared DAVIS bear masks and the bear MP4)")  # fmt: skip
    p.add_argument("--seconds", type=float, default=15.0, help="seconds of live per camera (the file loops)")
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    cameras = args.camera or [c for c in DEFAULT_CAMERAS if c.exists()]
    if not cameras:
        print(f"no camera file: give --camera FILE (the shared targets are not at {SHARED})", file=sys.stderr)
        return 2

    from hardware.calibration import load_calibration
    from studio.imitate.still import Imitator
    from studio.sim.hand import load_hand

    hand = load_hand()
    cal = load_calibration(None, hand)
    runs = []
    with Imitator() as imitator:
        imitator.retrieval_index()
        for cam in cameras:
            r = run_camera(_video_in(cam), args.seconds, imitator, hand, cal)
            runs.append(r)
            print(f"{Path(r['camera']).name}: {r['updates']} updates in {r['seconds']} s ({r['updates_per_s']}/s), "
                  f"latency p50 {r['latency_p50_ms']} ms p99 {r['latency_p99_ms']} ms, loss {r['loss_live']} vs "
                  f"offline first answer {r['loss_offline_first']} (gap {r['loss_gap']}), {r['collisions']} "
                  f"collisions, {r['limit_violations']} limit violations in {r['ticks']} ticks "
                  f"(tick lateness p99 {r['tick_late_p99_ms']} ms)")  # fmt: skip
    lat = np.concatenate([r.pop("_lat") for r in runs])
    live = np.concatenate([r["_gap"][0] for r in runs])
    offline = np.concatenate([r.pop("_gap")[1] for r in runs])
    seconds = sum(r["seconds"] for r in runs)
    record = {
        "latency_p50_ms": round(float(np.percentile(lat, 50)), 1) if len(lat) else None,
        "latency_p99_ms": round(float(np.percentile(lat, 99)), 1) if len(lat) else None,
        "updates_per_s": round(sum(r["updates"] for r in runs) / seconds, 2) if seconds else 0.0,
        "loss_gap": round(float(live.mean() - offline.mean()), 4) if len(live) else None,
        "collisions": sum(r["collisions"] for r in runs),
        "limit_violations": sum(r["limit_violations"] for r in runs),
        "cameras": runs,
    }
    print(json.dumps(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())
