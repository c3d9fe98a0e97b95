"""What a show played with a camera gives (plain data), its targets, its losses and its files.

:class:`KeyframeCapture` is one keyframe marker of the show: its commanded pose and simulated shadow, the camera's
shadow (or why there is none), the target and three losses (:data:`LOSSES`): the captured and the simulated shadow
against the target as the crop-aligned IoU loss that scores every result of a project (DESIGN §4: the shadow's box,
padded, made square, resized to 256², then ``1 − Σmin/Σmax``), and the captured against the simulated shadow as the
window IoU loss (both are in the backdrop window's pixels, so the rig's own error shows). :class:`ShowCaptureResult`
holds them with the playback; :func:`save_captures` writes ``real_vs_sim.png`` (one row per keyframe, target |
captured | simulated | overlay) and ``real_vs_sim.json``, and the masks of each keyframe when asked. Every face
(``play --camera``, the Export tab) reads these; the engine is :mod:`studio.project.show_capture`.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from studio.atomic import write_text
from studio.imitate.config import LossConfig
from studio.motion.show import Show
from studio.review.real_vs_sim import real_sim_row, real_sim_sheet
from studio.review.sheets import shadow_tile, write_png

LOSSES = ("captured_vs_target", "simulated_vs_target", "captured_vs_simulated")  # the keys of every capture's losses


def aligned_iou_loss(a: np.ndarray, b: np.ndarray, pad: float = LossConfig().pad, size: int | None = None) -> float:
    """``1 − IoU`` of two binary shadows ``(H, W)`` and ``(H', W')`` (1 = shadow), each on its own aligned crop
    (``pad`` px at 256, scaled with its side; resized to ``size``², default 256) as the project's losses see them:
    0 for two empty shadows, 1 when only one is empty."""
    from studio.imitate.rendered_loss import crop_batch  # numba kernels (and torch): loaded on first use
    from studio.sim.crop_pad import REFERENCE_SIDE, pad_pixels

    size = size or REFERENCE_SIDE

    a, b = (np.ascontiguousarray(np.asarray(x) != 0, dtype=np.uint8) for x in (a, b))
    if not a.any() or not b.any():
        return 0.0 if a.any() == b.any() else 1.0
    ca, cb = (crop_batch(x[None], pad_pixels(pad, *x.shape), size)[0] for x in (a, b))
    return float(1.0 - np.minimum(ca, cb).sum() / max(float(np.maximum(ca, cb).sum()), 1e-9))


@dataclass
class KeyframeCapture:
    """One keyframe marker of a show played with a camera."""

    index: int  # the marker's position in ``show.keyframes``
    show_t: float  # the keyframe's show time, s
    commanded: np.ndarray  # (21,) rad, the show's pose at the keyframe as the player sends it (stopped at the
    # calibration's soft limits), the hand's joint order
    simulated: np.ndarray  # (R, R) uint8, 1 = shadow: the commanded pose on the calibrated rig (mount roll included)
    target: np.ndarray | None  # (S, S) uint8, 1 = shadow: the keyframe's target, None when the show has none
    captured: np.ndarray | None = None  # (R, R) uint8, 1 = shadow: the camera's shadow in the window, None: no picture
    coverage: np.ndarray | None = None  # (R, R) float32 in [0, 1]: each window pixel's share in shadow
    losses: dict[str, float] = field(default_factory=dict)  # LOSSES → value (NaN: not computed)
    frame_t: float | None = None  # time.monotonic() when the frame arrived, s
    frame_index: int | None = None  # the camera's running frame index
    frame_show_t: float | None = None  # the show time at which the frame arrived, s (about: within a tick)
    measured: np.ndarray | None = None  # (21,) rad: the player's read-backs at the frame's time (NaN: never read)
    photo: np.ndarray | None = None  # (H, W, 3) uint8 BGR photograph, when kept
    error: str = ""  # why there is no captured shadow ("" when there is one)
    ramp_s: float = 0.0  # the ramp-in the show time is counted after, s

    @property
    def name(self) -> str:
        """``"k2 1.50 s"``: the marker and its show time."""
        return f"k{self.index} {self.show_t:.2f} s"


@dataclass
class ShowCaptureResult:
    """A show played with a camera: the player's result and one :class:`KeyframeCapture` per keyframe marker."""

    playback: Any  # hardware.playback_log.PlaybackResult: why it stopped, commanded vs measured
    captures: list[KeyframeCapture]  # in the show's keyframe order
    rig: Any  # studio.sim.shadow.Rig the simulated shadows were cast on (its resolution: the captures')
    title: str = ""  # the show's title
    camera_error: str = ""  # the camera's first failure during the show ("" when it worked throughout)

    def rows(self) -> list[dict[str, Any]]:
        """Per keyframe: ``keyframe``, ``show_time_s``, ``frame_show_time_s``, the :data:`LOSSES` (None where not
        computed) and ``error`` (JSON-ready)."""
        out = []
        for c in self.captures:
            shown = None if c.frame_show_t is None else round(c.frame_show_t, 4)
            row = {"keyframe": c.index, "show_time_s": round(c.show_t, 4), "frame_show_time_s": shown}
            out.append(row | {k: _num(c.losses.get(k)) for k in LOSSES} | {"error": c.error})
        return out

    def means(self) -> dict[str, float | None]:
        """Each loss's mean over the keyframes where it was computed (None where it never was)."""
        values = {k: [c.losses.get(k, math.nan) for c in self.captures] for k in LOSSES}
        return {k: _num(float(np.nanmean(v))) if np.isfinite(v).any() else None for k, v in values.items()}

    def summary(self) -> dict[str, Any]:
        """What the faces print last: the show, how it ended, the captures, per-keyframe rows and the means."""
        reason = getattr(self.playback.reason, "value", str(self.playback.reason))
        return {
            "show": self.title, "played": reason, "keyframes": len(self.captures),
            "captured": sum(c.captured is not None for c in self.captures), "camera_error": self.camera_error,
            "resolution": int(self.rig.resolution), "mean": self.means(), "per_keyframe": self.rows(),
        }  # fmt: skip

    def table(self) -> list[str]:
        """The per-keyframe table as text lines: time and the three losses (``-``: not computed)."""
        lines = [f"{'keyframe':>8} {'time s':>7} {'captured-target':>15} {'simulated-target':>16} "
                 f"{'captured-simulated':>18}"]  # fmt: skip
        for c in self.captures:
            v = [_text(c.losses.get(k)) for k in LOSSES]
            note = f"  {c.error}" if c.error else ""
            lines.append(f"{c.index:>8} {c.show_t:>7.2f} {v[0]:>15} {v[1]:>16} {v[2]:>18}{note}")
        return lines

    def sheet(self, tile: int = 160) -> np.ndarray:
        """``real_vs_sim.png``'s picture: one :func:`~studio.review.real_vs_sim.real_sim_row` per keyframe → RGB."""
        rows = [real_sim_row(c.target, c.captured, c.simulated, tile, c.losses, c.name) for c in self.captures]
        if not rows:
            return np.full((tile, tile, 3), 128, np.uint8)
        return real_sim_sheet(rows)


def _num(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), 5)


def _text(x: float | None) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.4f}"


def tick_s(playback: Any) -> float:
    """The player's tick period from a playback's tick times, s."""
    d = np.diff(np.asarray(playback.t, float))
    return float(d[d > 1e-9].min()) if (d > 1e-9).any() else 1 / 40


def measured_at(playback: Any, play_t: float, names: Sequence[str]) -> np.ndarray | None:
    """The player's read-backs of each joint interpolated at ``play_t`` s → ``(21,)`` rad in ``names`` order (NaN
    for a joint never read); None when nothing was read."""
    mt, mj, mq = (np.asarray(a) for a in (playback.measured_t, playback.measured_joint, playback.measured_rad))
    if not len(mt):
        return None
    out = np.full(len(names), np.nan)
    for j, name in enumerate(playback.joint_names):
        mine = mj == j
        if mine.any() and name in names:
            out[list(names).index(name)] = np.interp(play_t, mt[mine], mq[mine])
    return out


def place(captures: list[KeyframeCapture], playback: Any, t0: float, names: Sequence[str]) -> list[KeyframeCapture]:
    """Give each capture with a frame its show time and measured pose: ``t0`` is the ``time.monotonic()`` of play
    time 0 (the ramp's start), ``names`` the hand's joint order; the ramp is the one the player played. In place."""
    ramp_s = int(playback.ramp_ticks) * tick_s(playback)
    for c in captures:
        c.ramp_s = ramp_s
        if c.frame_t is not None and np.isfinite(t0):
            c.frame_show_t = c.frame_t - t0 - ramp_s
            c.measured = measured_at(playback, c.frame_t - t0, names)
    return captures


def save_captures(result: ShowCaptureResult, folder: Path, prefix: str = "", masks: bool = False,
                  tile: int = 160) -> dict[str, Path]:  # fmt: skip
    """Write ``<prefix>real_vs_sim.png`` and ``<prefix>real_vs_sim.json`` (:meth:`ShowCaptureResult.summary`) in
    ``folder``; with ``masks``, also ``k<i>_{target,captured,simulated}.png`` and ``k<i>_photo.png`` per keyframe.
    Returns the files by name."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    files = {"sheet": write_png(folder / f"{prefix}real_vs_sim.png", result.sheet(tile))}
    files["summary"] = write_text(folder / f"{prefix}real_vs_sim.json", json.dumps(result.summary(), indent=1) + "\n")
    for c in result.captures if masks else ():
        for what in ("target", "captured", "simulated"):
            image = getattr(c, what)
            if image is not None:
                files[f"k{c.index}_{what}"] = write_png(folder / f"k{c.index}_{what}.png", shadow_tile(image, None))
        if c.photo is not None:
            files[f"k{c.index}_photo"] = write_png(folder / f"k{c.index}_photo.png", c.photo[..., ::-1])
    return files


def show_targets(show: Show, project: Any = None, base_dir: Path | None = None) -> list[np.ndarray | None]:
    """One target mask (1 = shadow) or None per keyframe marker of ``show``: a marker whose ``target`` names a
    project frame (``"clip.gif#12"``: the source's file name and its frame) takes that frame's mask from ``project``
    (a :class:`~studio.project.project.Project`); one naming an image file (relative to ``base_dir``, e.g. the show
    file's folder) loads it as a still target; any other marker has none."""
    frames: dict[tuple[str, int], int] = {}
    if project is not None:
        for n, f in enumerate(project.frames):
            frames.setdefault((Path(project.sources[f.source].path).name, int(f.source_frame)), n)
    out: list[np.ndarray | None] = []
    for m in show.keyframes:
        ref, mask = m.target or "", None
        name, _, number = ref.rpartition("#")
        if project is not None and number.isdigit() and (name, int(number)) in frames:
            mask = np.asarray(project.state.targets[frames[(name, int(number))]], np.uint8)
        elif ref and base_dir is not None and (Path(base_dir) / ref).is_file():
            from studio.targets.images import load_target

            mask = load_target(Path(base_dir) / ref)
        out.append(mask)
    return out
