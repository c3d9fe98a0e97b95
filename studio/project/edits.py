"""Keyframe edits as pure functions: clustering a project's frames, and the artist's changes to the clusters.

Frames are clustered per source (:func:`~studio.targets.keyframes.cluster_keyframes` on the expressive masks the
artist sees: automatic ∪ additions minus erasures), keyframes numbered in order of first appearance across the
sources. The clusters at a τ are cut from each source's merge order (:func:`merge_orders`), which a project keeps for
what the clustering reads (:func:`clustering_reads`): a count or a recluster at another τ merges nothing again.

A keyframe keeps its id while it exists; a re-clustering gives a cluster with the same frames (by frame key) and the
same representative as before that keyframe's old id (and its time and hold), so its result is kept.

The artist's edits keep every frame in exactly one keyframe of its own source. When a keyframe's members change,
its representative stays if it is still a member; otherwise the member nearest the members' mean expressive mask
(L2) is chosen, the rule clustering uses.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from studio.project.state import Frame, Keyframe, ProjectError, ProjectState
from studio.targets.expressive import combine
from studio.targets.keyframes import KeyframeConfig, merge_order
from studio.targets.merging import MergeOrder


def combined_masks(state: ProjectState) -> np.ndarray:
    """The expressive masks the artist sees, ``(N, S, S)`` uint8: :func:`combined_mask` of every frame."""
    out = np.empty_like(state.auto)
    for i in range(len(state.frames)):
        out[i] = combined_mask(state, i)
    return out


def combined_mask(state: ProjectState, i: int) -> np.ndarray:
    """Frame ``i``'s expressive mask as the artist sees it, ``(S, S)`` uint8: ``combine(auto, additions, erasures)``
    (one frame: a tab showing the frame in view need not combine every frame of a long video)."""
    key = state.frames[i].key
    return combine(state.auto[i], state.additions.get(key), state.erasures.get(key))


def nearest_mean(members: Sequence[int], masks: np.ndarray) -> int:
    """The member whose mask ``masks[i] (S, S)`` is nearest (L2) the members' mean mask; the first on a tie."""
    m = np.asarray(masks, np.float32)[list(members)].reshape(len(members), -1)
    d = ((m - m.mean(axis=0)) ** 2).sum(axis=1)
    return int(list(members)[int(np.argmin(d))])


def _ordered(keyframes: list[Keyframe]) -> tuple[Keyframe, ...]:
    return tuple(sorted(keyframes, key=lambda kf: kf.members[0]))


def cluster(
    frames: Sequence[Frame],
    masks: np.ndarray,
    cfg: KeyframeConfig,
    old: Sequence[Keyframe] = (),
    old_frames: Sequence[Frame] = (),
    next_id: int = 0,
    shadows: np.ndarray | None = None,
    orders: Sequence[MergeOrder] | None = None,
) -> tuple[tuple[Keyframe, ...], int]:
    """Keyframes of ``frames`` from their expressive ``masks (N, S, S)``, clustered per source (by shape: each
    cropped by its frame's shadow box in ``shadows (N, S, S)``, the frames' targets), and the next free id.

    ``orders``: the :func:`merge_orders` of these frames, masks and shadows (any τ), when the caller has them; else
    they are worked out here. ``old`` keyframes (over ``old_frames``) lend their id, time and hold to a cluster with
    the same frame keys and representative; every other cluster gets a new id from ``next_id`` on."""
    keys = [f.key for f in frames]
    by_content = {(tuple(old_frames[m].key for m in kf.members), old_frames[kf.representative].key): kf for kf in old}
    used = {kf.id for kf in old}
    found: list[Keyframe] = []
    sources = per_source(frames)
    orders = merge_orders(frames, masks, cfg, shadows) if orders is None else orders
    if [len(o.embeddings) for o in orders] != [len(idx) for idx in sources]:
        raise ValueError("the merge orders given are not of these frames (another state of the project)")
    for idx, order in zip(sources, orders, strict=True):
        c = order.clusters(cfg.tau)
        for group, rep in zip(c.members, c.representatives, strict=True):
            members = tuple(int(idx[m]) for m in group)
            rep = int(idx[rep])
            was = by_content.get((tuple(keys[m] for m in members), keys[rep]))
            if was is not None:
                found.append(Keyframe(was.id, rep, members, was.time_s, was.hold))
            else:
                while next_id in used:
                    next_id += 1
                found.append(Keyframe(next_id, rep, members))
                used.add(next_id)
    return _ordered(found), max(next_id, max(used, default=-1) + 1)


def merge_orders(
    frames: Sequence[Frame], masks: np.ndarray, cfg: KeyframeConfig, shadows: np.ndarray | None = None
) -> list[MergeOrder]:
    """Per source, in :func:`cluster`'s order, the :class:`~studio.targets.keyframes.MergeOrder` of its frames: the
    keyframe count :func:`cluster` makes at any τ is ``sum(o.count(tau) for o in merge_orders(...))``."""
    return [merge_order(masks[idx], cfg, None if shadows is None else np.asarray(shadows)[idx])
            for idx in per_source(frames)]  # fmt: skip


def clustering_reads(state: ProjectState) -> tuple:
    """What :func:`merge_orders` reads in project state ``state`` (frames, targets, automatic masks, paint, the
    clustering's settings but τ), to compare with :func:`same_reads`: edits replace these objects, never change
    them."""
    return state.frames, state.targets, state.auto, state.additions, state.erasures, replace(state.clustering, tau=0.0)


def same_reads(a: tuple, b: tuple) -> bool:
    """Whether two :func:`clustering_reads` are of the same clustering inputs (the same objects, equal settings)."""
    return all(x is y for x, y in zip(a[:-1], b[:-1], strict=True)) and a[-1] == b[-1]


def per_source(frames: Sequence[Frame]) -> list[np.ndarray]:
    """The frame indices of each source, ``(n_s,)`` int each, sources in ascending order (how frames are clustered)."""
    return [np.array([i for i, f in enumerate(frames) if f.source == s]) for s in sorted({f.source for f in frames})]


def _owner(keyframes: Sequence[Keyframe], frame: int) -> Keyframe:
    for kf in keyframes:
        if frame in kf.members:
            return kf
    raise ProjectError(f"no frame {frame} in this project's keyframes")


def _check_frame(frames: Sequence[Frame], frame: int) -> None:
    if not 0 <= frame < len(frames):
        raise ProjectError(f"no frame {frame}: this project has frames 0 to {len(frames) - 1}")


def _without(kf: Keyframe, frame: int, masks: np.ndarray) -> Keyframe | None:
    """``kf`` with ``frame`` taken out (None when nothing is left), the representative re-chosen when it left."""
    members = tuple(m for m in kf.members if m != frame)
    if not members:
        return None
    rep = kf.representative if kf.representative in members else nearest_mean(members, masks)
    return replace(kf, representative=rep, members=members, edited=True)


def add_keyframe(
    keyframes: Sequence[Keyframe], frames: Sequence[Frame], frame: int, masks: np.ndarray, next_id: int
) -> tuple[tuple[Keyframe, ...], int]:
    """``frame`` becomes a keyframe of its own (taken out of its cluster); returns the keyframes and the next id."""
    _check_frame(frames, frame)
    owner = _owner(keyframes, frame)
    if owner.members == (frame,):
        raise ProjectError(f"frame {frame} is already keyframe {owner.id} on its own")
    rest = _without(owner, frame, masks)
    new = Keyframe(next_id, frame, (frame,), edited=True)
    out = [kf for kf in keyframes if kf.id != owner.id] + [rest, new]
    return _ordered(out), next_id + 1


def remove_keyframe(
    keyframes: Sequence[Keyframe], frames: Sequence[Frame], k: int, masks: np.ndarray
) -> tuple[Keyframe, ...]:
    """Keyframe ``k`` removed: each of its frames joins the keyframe of the same source whose representative's
    expressive mask is nearest its own (L2)."""
    gone = next((kf for kf in keyframes if kf.id == k), None)
    if gone is None:
        raise ProjectError(f"no keyframe {k}; the keyframes are {[kf.id for kf in keyframes]}")
    source = frames[gone.representative].source
    others = [kf for kf in keyframes if kf.id != k and frames[kf.representative].source == source]
    if not others:
        raise ProjectError(f"keyframe {k} is the only keyframe of source {source}: every source needs one")
    flat = np.asarray(masks, np.float32).reshape(len(masks), -1)
    reps = np.stack([flat[kf.representative] for kf in others])
    joined: dict[int, list[int]] = {kf.id: list(kf.members) for kf in others}
    for m in gone.members:
        best = others[int(np.argmin(((reps - flat[m]) ** 2).sum(axis=1)))]
        joined[best.id].append(m)
    out = [kf for kf in keyframes if kf.id != k and kf.id not in joined]
    for kf in others:
        members = tuple(sorted(joined[kf.id]))
        out.append(kf if members == kf.members else replace(kf, members=members, edited=True))
    return _ordered(out)


def move_frame(
    keyframes: Sequence[Keyframe], frames: Sequence[Frame], frame: int, k: int, masks: np.ndarray
) -> tuple[Keyframe, ...]:
    """``frame`` moved into keyframe ``k``'s cluster (of the same source); a keyframe left empty disappears."""
    _check_frame(frames, frame)
    owner, target = _owner(keyframes, frame), next((kf for kf in keyframes if kf.id == k), None)
    if target is None:
        raise ProjectError(f"no keyframe {k}; the keyframes are {[kf.id for kf in keyframes]}")
    if owner.id == k:
        raise ProjectError(f"frame {frame} is already in keyframe {k}")
    if frames[target.representative].source != frames[frame].source:
        raise ProjectError(f"frame {frame} is from source {frames[frame].source}, keyframe {k} from another source")
    rest = _without(owner, frame, masks)
    moved = replace(target, members=tuple(sorted((*target.members, frame))), edited=True)
    out = [kf for kf in keyframes if kf.id not in (owner.id, k)] + [moved] + ([rest] if rest else [])
    return _ordered(out)


def assignment(keyframes: Sequence[Keyframe], n_frames: int) -> np.ndarray:
    """``(N,)`` int: the position (first-appearance number) of each frame's keyframe in ``keyframes``."""
    out = np.full(n_frames, -1, np.int64)
    for pos, kf in enumerate(keyframes):
        out[list(kf.members)] = pos
    return out
