"""The edits of a :class:`~studio.project.project.Project`, one method each (mixed into ``Project``).

Each edit builds the new :class:`~studio.project.project_format.ProjectState` from the current one under the
project's lock and hands it to ``Project._commit``, which saves it atomically and records the change for undo. An
edit that raises leaves the project as it was. Edits that change how sources become frames (sampling, threshold,
segmentation, a relinked source with new content) re-read the sources and re-cluster; painted strokes are kept by
frame key, and a cluster whose frames and representative are unchanged keeps its id (and so its result).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from studio.imitate.config import LossConfig
from studio.motion.bounds import MAX_SHOW_S
from studio.motion.show import Show
from studio.progress import ProgressFn
from studio.project import edits
from studio.project.sources import load_sources, locate, make_source
from studio.project.state import Mount, PoseResult, ProjectError, ProjectState, frozen
from studio.project.status import SourceMissing
from studio.sim.roll import roll_deg
from studio.targets.images import read_grey

log = logging.getLogger(__name__)

KEEP: Any = type("Keep", (), {"__repr__": lambda self: "KEEP"})()  # "leave this setting as it is"


def _mask_arg(mask: Any, shape: tuple[int, ...] | None, what: str) -> np.ndarray:
    """An array or a PNG path → a read-only mask uint8 {0, 1} (nonzero / brighter than mid-grey = set)."""
    m = read_grey(mask) > 127 if isinstance(mask, (str, Path)) else np.asarray(mask)
    if shape is not None and m.shape != shape:
        raise ProjectError(f"{what} of shape {m.shape} does not fit: expected {shape}")
    if m.ndim != 2:
        raise ProjectError(f"{what} must be an (H, W) image, not an array of shape {m.shape}")
    return frozen(m)


class Editing:
    """Edit methods of ``Project`` (it provides ``path``, ``_state``, ``_lock``, ``_commit``, ``_check_sources``,
    ``_now``, ``keyframe_inputs`` and ``show_inputs``)."""

    def _paths(self) -> list[Path]:
        paths = []
        for i, src in enumerate(self._state.sources):
            where = locate(src, self.path)
            if where is None:
                raise SourceMissing(
                    f"source {i} is missing (it was at {src.absolute}): put it back, or relink source {i} to where it "
                    "is now", i,
                )  # fmt: skip
            paths.append(where)
        return paths

    def _reloaded(
        self, state: ProjectState, progress: ProgressFn | None = None, paths: list[Path] | None = None
    ) -> ProjectState:
        """``state`` with its sources re-read (from ``paths``, default where the current sources are) at its
        settings, re-clustered (ids kept for unchanged clusters), results of keyframes that no longer exist dropped;
        painted strokes are kept by frame key."""
        paths = self._paths() if paths is None else paths
        sources, frames, targets, auto = load_sources(state.sources, paths, state.video, state.still, progress)
        new = replace(state, sources=sources, frames=frames, targets=frozen(targets), auto=frozen(auto))
        keyframes, next_id = edits.cluster(
            frames,
            edits.combined_masks(new),
            state.clustering,
            state.keyframes,
            state.frames,
            state.next_id,
            shadows=new.targets,
        )
        ids = {kf.id for kf in keyframes}
        results = {k: r for k, r in state.results.items() if k in ids}
        return replace(new, keyframes=keyframes, next_id=next_id, results=results)

    def _edit_reloading(self, label: str, progress: ProgressFn | None = None, **changes: Any) -> None:
        with self._lock:
            new = self._reloaded(replace(self._state, **changes), progress)
            self._commit(label, new)
            self._check_sources()

    def set_sampling(self, hz: float = KEEP, fps: float | None = KEEP, progress: ProgressFn | None = None) -> None:
        """Re-sample the videos at ``hz`` (and a frame folder's ``fps``): frames, masks and keyframes recomputed."""
        cfg = replace(self._state.video, **{k: v for k, v in (("hz", hz), ("fps", fps)) if v is not KEEP})
        self._edit_reloading(f"sampling {cfg.hz:g} Hz", progress, video=cfg)

    def set_threshold(self, video: float | None = KEEP, still: float | None = KEEP, progress=None) -> None:
        """The shadow threshold of videos (``VideoConfig.threshold``) and/or stills (``TargetConfig.threshold``);
        None = Otsu. Frames, masks and keyframes recomputed."""
        v = self._state.video if video is KEEP else replace(self._state.video, threshold=video)
        s = self._state.still if still is KEEP else replace(self._state.still, threshold=still)
        self._edit_reloading(f"threshold video {v.threshold}, still {s.threshold}", progress, video=v, still=s)

    def set_segmentation(
        self,
        source: int,
        box: tuple[int, int, int, int] | None = None,
        first_mask: np.ndarray | str | Path | None = None,
        progress: ProgressFn | None = None,
    ) -> None:
        """How colour footage ``source`` is segmented: a first-frame ``box`` (x, y, w, h) or ``first_mask`` (an
        ``(H, W)`` array or a PNG path), or neither (no segmentation). Frames and keyframes recomputed."""
        srcs = list(self._state.sources)
        if not 0 <= source < len(srcs):
            raise ProjectError(f"no source {source}: this project has sources 0 to {len(srcs) - 1}")
        mask = None if first_mask is None else _mask_arg(first_mask, None, "the first mask")
        path = str(first_mask) if isinstance(first_mask, (str, Path)) else None
        srcs[source] = replace(srcs[source], box=None if box is None else tuple(int(v) for v in box),
                               first_mask=mask, first_mask_path=path)  # fmt: skip
        self._edit_reloading(f"segmentation of source {source}", progress, sources=tuple(srcs))

    def relink_source(self, source: int, path: str | Path, progress: ProgressFn | None = None) -> None:
        """Source ``source`` is now at ``path``: the same content keeps every result; other content is re-read."""
        with self._lock:
            srcs = list(self._state.sources)
            if not 0 <= source < len(srcs):
                raise ProjectError(f"no source {source}: this project has sources 0 to {len(srcs) - 1}")
            found = make_source(path)
            old = srcs[source]
            srcs[source] = replace(old, path=found.path, absolute=found.absolute)
            new = replace(self._state, sources=tuple(srcs))
            if found.sha256 != old.sha256 or found.kind != old.kind:
                new = self._reloaded(replace(new, sources=tuple(srcs)), progress)
            self._commit(f"relink source {source} to {path}", new)
            self._check_sources()

    def reload_sources(self, progress: ProgressFn | None = None) -> None:
        """Re-read every source (after one changed on disk): frames, masks and keyframes recomputed."""
        self._edit_reloading("reload sources", progress)

    def add_source(
        self,
        path: str | Path,
        box: tuple[int, int, int, int] | None = None,
        first_mask: np.ndarray | str | Path | None = None,
        progress: ProgressFn | None = None,
    ) -> int:
        """Add ``path`` (a still, a video or a folder of frames) as the last source; returns its index. ``box`` /
        ``first_mask`` segment colour footage (as :meth:`set_segmentation`). Frames, masks and keyframes
        recomputed (the other sources' keyframes keep their ids)."""
        src = make_source(path)
        if src.kind != "still" and (box is not None or first_mask is not None):
            mask = None if first_mask is None else _mask_arg(first_mask, None, "the first mask")
            src = replace(src, box=None if box is None else tuple(int(v) for v in box), first_mask=mask,
                          first_mask_path=str(first_mask) if isinstance(first_mask, (str, Path)) else None)  # fmt: skip
        with self._lock:
            state = replace(self._state, sources=self._state.sources + (src,))
            new = self._reloaded(state, progress, self._paths() + [Path(src.absolute)])
            self._commit(f"add source {path}", new)
            self._check_sources()
            return len(self._state.sources) - 1

    def recluster(self, tau: float | None = None) -> None:
        """Cluster the frames into keyframes again (at ``tau``, default the current one), on the expressive masks
        the artist sees (paint included). Hand edits of the keyframes are replaced."""
        with self._lock:
            s = self._state
            cfg = s.clustering if tau is None else replace(s.clustering, tau=float(tau))
            keyframes, next_id = edits.cluster(s.frames, self.combined_masks(), cfg, s.keyframes, s.frames, s.next_id,
                                               shadows=s.targets)  # fmt: skip
            ids = {kf.id for kf in keyframes}
            results = {k: r for k, r in s.results.items() if k in ids}
            self._commit(f"recluster at tau {cfg.tau:g}", replace(s, clustering=cfg, keyframes=keyframes,
                                                                  next_id=next_id, results=results))  # fmt: skip

    def set_weights(self, weights: LossConfig | None = None, **fields: float) -> None:
        """The loss weights: a whole ``LossConfig`` and/or some of its fields (``w_iou=0.5``)."""
        with self._lock:
            cfg = replace(weights or self._state.weights, **fields)
            self._commit("loss weights", replace(self._state, weights=cfg))

    def set_roll(self, roll: str | float) -> None:
        """The mount roll: ``"auto"`` (chosen at the start of the next run, for the whole show) or degrees. A new
        roll makes every keyframe stale (each pose is chosen for its roll); "auto" again chooses again."""
        with self._lock:
            mount = Mount.from_setting(roll)
            self._commit(f"mount roll {roll}", replace(self._state, mount=mount))

    def set_chosen_roll(self, roll: float, loss: float | None = None, upright_loss: float | None = None) -> None:
        """What ``auto`` chose: ``roll`` rad (with the losses it compared), kept until the artist sets the roll."""
        with self._lock:
            mount = Mount(auto=True, roll=float(roll), chosen=True, loss=loss, upright_loss=upright_loss)
            self._commit(f"mount roll chosen: {roll_deg(roll):g}°", replace(self._state, mount=mount))

    # ---------------------------------------------------------------- edits: keyframes
    def _keyframes(self, label: str, keyframes, next_id: int | None = None) -> None:
        s = self._state
        ids = {kf.id for kf in keyframes}
        results = {k: r for k, r in s.results.items() if k in ids}
        new = replace(s, keyframes=tuple(keyframes), results=results, next_id=s.next_id if next_id is None else next_id)
        self._commit(label, new)

    def add_keyframe(self, frame: int) -> int:
        """Frame ``frame`` becomes a keyframe of its own; returns the new keyframe's id."""
        with self._lock:
            s = self._state
            kfs, next_id = edits.add_keyframe(s.keyframes, s.frames, frame, self.combined_masks(), s.next_id)
            self._keyframes(f"add keyframe at frame {frame}", kfs, next_id)
            return s.next_id

    def remove_keyframe(self, k: int) -> None:
        """Keyframe ``k`` removed; its frames join the nearest keyframes of their source."""
        with self._lock:
            s = self._state
            kfs = edits.remove_keyframe(s.keyframes, s.frames, k, self.combined_masks())
            self._keyframes(f"remove keyframe {k}", kfs)

    def move_frame(self, frame: int, k: int) -> None:
        """Frame ``frame`` now plays keyframe ``k``'s pose (a keyframe left with no frames disappears)."""
        with self._lock:
            s = self._state
            kfs = edits.move_frame(s.keyframes, s.frames, frame, k, self.combined_masks())
            self._keyframes(f"move frame {frame} to keyframe {k}", kfs)

    def _set_keyframe(self, label: str, k: int, **changes: Any) -> None:
        with self._lock:
            kf = self._state.keyframe(k)
            kfs = [replace(kf, **changes) if x.id == k else x for x in self._state.keyframes]
            self._keyframes(label, kfs)

    def set_keyframe_time(self, k: int, time_s: float | None) -> None:
        """Keyframe ``k``'s show time, s (None: the video's clock)."""
        if time_s is not None and not (math.isfinite(time_s) and 0 <= time_s <= MAX_SHOW_S):
            raise ProjectError(f"a keyframe time is a number of seconds in [0, {MAX_SHOW_S:g}], not {time_s:g}")
        t = None if time_s is None else float(time_s)
        self._set_keyframe(f"keyframe {k} at {t} s", k, time_s=t)

    def set_hold(self, k: int, hold: bool) -> None:
        """Whether the hand comes to rest at keyframe ``k``'s pose."""
        self._set_keyframe(f"keyframe {k} hold {bool(hold)}", k, hold=bool(hold))

    # ---------------------------------------------------------------- edits: paint
    def _frame_key(self, frame: int) -> str:
        if not 0 <= frame < len(self._state.frames):
            raise ProjectError(f"no frame {frame}: this project has frames 0 to {len(self._state.frames) - 1}")
        return self._state.frames[frame].key

    def paint(self, frame: int, additions: np.ndarray | None = None, erasures: np.ndarray | None = None) -> None:
        """Set frame ``frame``'s painted layers ``(S, S)`` (nonzero = painted; an empty layer removes it); None
        leaves a layer as it is. The automatic mask is kept apart; erasures win over additions."""
        with self._lock:
            s, key = self._state, self._frame_key(frame)
            layers = {"additions": dict(s.additions), "erasures": dict(s.erasures)}
            for name, given in (("additions", additions), ("erasures", erasures)):
                if given is None:
                    continue
                m = _mask_arg(given, s.auto.shape[1:], f"frame {frame}'s {name}")
                if m.any():
                    layers[name][key] = m
                else:
                    layers[name].pop(key, None)
            self._commit(f"paint frame {frame}", replace(s, **layers))

    def clear_paint(self, frame: int, additions: bool = True, erasures: bool = True) -> None:
        """Remove frame ``frame``'s painted additions and/or erasures."""
        with self._lock:
            s, key = self._state, self._frame_key(frame)
            add = {k: v for k, v in s.additions.items() if not (additions and k == key)}
            era = {k: v for k, v in s.erasures.items() if not (erasures and k == key)}
            self._commit(f"clear paint of frame {frame}", replace(s, additions=add, erasures=era))

    # ---------------------------------------------------------------- edits: results and the show
    def set_result(
        self,
        k: int,
        pose: Mapping[str, float] | np.ndarray,
        loss: Mapping[str, float],
        shadow: np.ndarray,
        inputs: str | None = None,
        evaluation: Mapping[str, float] | None = None,
        collision_free: bool = True,
        seconds: float = 0.0,
    ) -> None:
        """Keyframe ``k``'s optimisation result: ``pose`` (joint name → rad, or ``(21,)`` rad in the hand's joint
        order), loss components, rendered ``shadow (R, R)``; ``inputs`` = :meth:`keyframe_inputs` captured when the
        work began (default: now). A result from inputs that changed meanwhile is kept, marked stale."""
        if not isinstance(pose, Mapping):
            from studio.sim.hand import load_hand

            names = load_hand().joint_names
            theta = np.asarray(pose, dtype=np.float64).ravel()
            if len(theta) != len(names):
                raise ProjectError(f"a pose of {len(theta)} angles does not fit the hand's {len(names)} joints")
            pose = dict(zip(names, theta.tolist(), strict=True))
        if not all(math.isfinite(float(v)) for v in pose.values()):
            raise ProjectError(f"keyframe {k}'s pose has a non-finite angle: {dict(pose)}")
        shadow = np.asarray(shadow)
        if shadow.ndim != 2:
            raise ProjectError(f"a shadow is an (R, R) image, not an array of shape {shadow.shape}")
        with self._lock:
            now = self.keyframe_inputs(k)
            if inputs is not None and inputs != now:
                log.warning("%s: keyframe %d's result was computed from inputs that changed since: stale", self.path, k)
            result = PoseResult(
                pose={str(n): float(v) for n, v in pose.items()}, loss={n: float(v) for n, v in loss.items()},
                shadow=frozen(shadow), inputs=inputs or now,
                evaluation={n: float(v) for n, v in (evaluation or {}).items()},
                collision_free=bool(collision_free), seconds=float(seconds),
            )  # fmt: skip
            self._commit(f"result of keyframe {k}", replace(self._state, results={**self._state.results, k: result}))

    def set_show(self, show: Show | None, inputs: str | None = None) -> None:
        """The planned show (None removes it); ``inputs`` = :meth:`show_inputs` captured when planning began."""
        with self._lock:
            if show is not None and not show.created:
                show = replace(show, created=self._now())
            ins = None if show is None else (inputs or self.show_inputs())
            self._commit("planned show" if show else "remove show", replace(self._state, show=show, show_inputs=ins))
