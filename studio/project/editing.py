"""The edits of a :class:`~studio.project.project.Project`'s sources and settings (sampling, threshold,
segmentation, relinked or added sources, clustering, loss weights, the mount roll), one method each (mixed into
``Project``; its keyframes, paint, results and show: :mod:`studio.project.keyframe_editing`).

Each edit builds the new :class:`~studio.project.project_format.ProjectState` from the current one under the
project's lock and hands it to ``Project._commit``, which saves it atomically and records the change for undo. An
edit that raises leaves the project as it was. Edits that change how sources become frames (sampling, threshold,
segmentation, a relinked source with new content) re-read the sources and re-cluster; painted strokes are kept by
frame key, and a cluster whose frames and representative are unchanged keeps its id (and so its result).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from studio.errors import ProgressFn
from studio.imitate.config import LossConfig
from studio.project import edits
from studio.project.sources import load_sources, locate, make_source
from studio.project.state import Mount, MountApart, ProjectError, ProjectState, frozen
from studio.project.status import SourceMissing
from studio.sim.roll import roll_deg
from studio.targets.images import read_grey
from studio.targets.merging import MergeOrder
from studio.targets.pockets import POCKET_REACH

log = logging.getLogger(__name__)

KEEP: Any = type("Keep", (), {"__repr__": lambda self: "KEEP"})()  # "leave this setting as it is"
ORDERS_KEPT = 4  # clusterings' merge orders a project keeps (the state now and a few an undo or redo returns to)


def mask_arg(mask: Any, shape: tuple[int, ...] | None, what: str) -> np.ndarray:
    """An array or a PNG path → a read-only mask uint8 {0, 1} (nonzero / brighter than mid-grey = set)."""
    m = read_grey(mask) > 127 if isinstance(mask, (str, Path)) else np.asarray(mask)
    if shape is not None and m.shape != shape:
        raise ProjectError(f"{what} of shape {m.shape} does not fit: expected {shape}")
    if m.ndim != 2:
        raise ProjectError(f"{what} must be an (H, W) image, not an array of shape {m.shape}")
    return frozen(m)


class Editing:
    """Source and setting edits of ``Project`` (it provides ``path``, ``_state``, ``_lock``, ``_orders``,
    ``_commit``, ``_check_sources`` and ``combined_masks``)."""

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
            orders=self._merge_orders_of(new),
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

    def set_threshold(
        self, video: float | None = KEEP, still: float | None = KEEP, pockets: bool = KEEP, progress=None
    ) -> None:
        """The shadow threshold of videos (``VideoConfig.threshold``) and/or stills (``TargetConfig.threshold``);
        None = Otsu; ``pockets``: whether the stills' crease pockets are filled (``TargetConfig.pocket_reach``: the
        default reach, or 0 to keep them as the threshold cuts them; footage fills none). One edit: frames, masks
        and keyframes recomputed once."""
        v = self._state.video if video is KEEP else replace(self._state.video, threshold=video)
        s = self._state.still if still is KEEP else replace(self._state.still, threshold=still)
        said = [] if video is KEEP and still is KEEP else [f"threshold video {v.threshold}, still {s.threshold}"]
        if pockets is not KEEP:
            s = replace(s, pocket_reach=POCKET_REACH if pockets else 0.0)
            said.append(f"crease pockets {'filled' if pockets else 'kept'}")
        self._edit_reloading("; ".join(said) or "threshold unchanged", progress, video=v, still=s)

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
        mask = None if first_mask is None else mask_arg(first_mask, None, "the first mask")
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
            mask = None if first_mask is None else mask_arg(first_mask, None, "the first mask")
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
                                               shadows=s.targets, orders=self._merge_orders_of(s))  # fmt: skip
            ids = {kf.id for kf in keyframes}
            results = {k: r for k, r in s.results.items() if k in ids}
            self._commit(f"recluster at tau {cfg.tau:g}", replace(s, clustering=cfg, keyframes=keyframes,
                                                                  next_id=next_id, results=results))  # fmt: skip

    def merge_orders(self, wait: bool = True) -> list[MergeOrder] | None:
        """Per source, the clustering's :class:`~studio.targets.keyframes.MergeOrder` of the project as it is now
        (:func:`edits.merge_orders`): the keyframe count at any τ, and the keyframes :meth:`recluster` makes at it,
        without clustering again. Worked out once for what the clustering reads (seconds on a long video; any thread
        may ask); with ``wait`` False, None when they are not worked out yet."""
        return self._merge_orders_of(self._state, wait)

    def _merge_orders_of(self, s: ProjectState, wait: bool = True) -> list[MergeOrder] | None:
        reads = edits.clustering_reads(s)
        kept = self._orders  # replaced whole, never changed in place: safe to read from any thread
        for was, orders in kept:
            if edits.same_reads(was, reads):
                return orders
        if not wait:
            return None
        orders = edits.merge_orders(s.frames, edits.combined_masks(s), s.clustering, s.targets)
        others = [e for e in self._orders if not edits.same_reads(e[0], reads)]
        self._orders = [(reads, orders), *others][:ORDERS_KEPT]
        return orders

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

    def set_chosen_roll(
        self, roll: float, loss: float | None = None, upright_loss: float | None = None,
        apart: Sequence[MountApart] = (),
    ) -> None:  # fmt: skip
        """What ``auto`` chose: ``roll`` rad (with the losses it compared and the keyframes it casts clearly worse
        than a roll of their own would), kept until the artist sets the roll."""
        with self._lock:
            mount = Mount(auto=True, roll=float(roll), chosen=True, loss=loss, upright_loss=upright_loss,
                          apart=tuple(apart))  # fmt: skip
            self._commit(f"mount roll chosen: {roll_deg(roll):g}°", replace(self._state, mount=mount))

    def set_roll_costs(self, roll: float, apart: Sequence[MountApart]) -> None:
        """What a roll the artist set (``roll`` rad) costs: the keyframes it casts clearly worse than a roll of their
        own would, kept with it; nothing when the roll has changed since it was measured, or the costs are known."""
        with self._lock:
            m = self._state.mount
            if not m.auto and m.roll == roll and m.apart != tuple(apart):
                self._commit("mount roll measured", replace(self._state, mount=replace(m, apart=tuple(apart))))
