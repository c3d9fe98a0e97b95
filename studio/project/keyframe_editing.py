"""The edits of a :class:`~studio.project.project.Project` that change its keyframes, painted strokes, results and
show, one method each (mixed into ``Project``; the edits of its sources and settings: :mod:`studio.project.editing`).

Each builds the new state under the project's lock and hands it to ``Project._commit`` (saved atomically, recorded
for undo); one that raises leaves the project as it was. A result computed from inputs that changed meanwhile is
kept, marked stale.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np

from studio.motion.bounds import MAX_SHOW_S
from studio.motion.show import Show
from studio.project import edits
from studio.project.editing import mask_arg
from studio.project.state import AWAITS, PoseResult, ProjectError, frozen

log = logging.getLogger(__name__)


class KeyframeEditing:
    """Keyframe, paint, result and show edits of ``Project`` (it provides ``path``, ``_state``, ``_lock``,
    ``_commit``, ``_now``, ``combined_masks``, ``keyframe_inputs`` and ``show_inputs``)."""

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
                m = mask_arg(given, s.auto.shape[1:], f"frame {frame}'s {name}")
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
        awaits: str = "",
    ) -> None:
        """Keyframe ``k``'s optimisation result: ``pose`` (joint name → rad, or ``(21,)`` rad in the hand's joint
        order), loss components, rendered ``shadow (R, R)``; ``inputs`` = :meth:`keyframe_inputs` captured when the
        work began (default: now); ``awaits``: what the run saving it still owes it (``AWAITS``; "together": it
        refines it with its neighbours next, :mod:`studio.project.run_together`). A result from inputs that changed
        meanwhile is kept, marked stale."""
        with self._lock:
            result = self._result(k, pose, loss, shadow, inputs, evaluation, collision_free, seconds, awaits)
            self._commit(f"result of keyframe {k}", replace(self._state, results={**self._state.results, k: result}))

    def refined_together(self, ids: list[int], moved: Mapping[int, Mapping[str, Any]] | None = None) -> None:
        """Keyframes ``ids`` refined together, in one edit (one undo): the results in ``moved`` (keyframe id →
        :meth:`set_result`'s arguments after ``k``) replace theirs, and the other results of ``ids`` no longer await
        it (their poses kept); nothing changes when nothing moved and nothing awaited it."""
        with self._lock:
            s = self._state
            new = {k: self._result(k, **args) for k, args in (moved or {}).items()}
            done = {k: replace(r, awaits="") for k in ids if (r := s.results.get(k)) and r.awaits == "together"}
            if new or done:
                label = f"keyframes {ids[0]}–{ids[-1]} refined together"
                self._commit(label, replace(s, results={**s.results, **done, **new}))

    def _result(
        self, k: int, pose: Mapping[str, float] | np.ndarray, loss: Mapping[str, float], shadow: np.ndarray,
        inputs: str | None = None, evaluation: Mapping[str, float] | None = None, collision_free: bool = True,
        seconds: float = 0.0, awaits: str = "",
    ) -> PoseResult:  # fmt: skip
        """The :class:`PoseResult` :meth:`set_result` saves (arguments checked: a ProjectError says what is wrong)."""
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
        if awaits != "" and awaits not in AWAITS:
            raise ProjectError(f"a result awaits one of {sorted(AWAITS)} or nothing, not {awaits!r}")
        now = self.keyframe_inputs(k)
        if inputs is not None and inputs != now:
            log.warning("%s: keyframe %d's result was computed from inputs that changed since: stale", self.path, k)
        return PoseResult(
            pose={str(n): float(v) for n, v in pose.items()}, loss={n: float(v) for n, v in loss.items()},
            shadow=frozen(shadow), inputs=inputs or now,
            evaluation={n: float(v) for n, v in (evaluation or {}).items()},
            collision_free=bool(collision_free), seconds=float(seconds), awaits=awaits,
        )  # fmt: skip

    def optimise_again(self, ids: list[int]) -> None:
        """The results of keyframes ``ids`` are to be optimised again (a run found a move between two sources too
        fast for the servos, :func:`~studio.project.show_timing.seams_out_of_reach`): stale until they are, so a run
        stopped before it leaves them for the next (its new result clears it); ids without a result are skipped."""
        with self._lock:
            s = self._state
            again = {k: replace(r, awaits="again") for k in ids if (r := s.results.get(k)) is not None}
            if again:
                which = ", ".join(map(str, sorted(again)))
                label = f"keyframe{'s' * (len(again) > 1)} {which} to optimise again: a move to another source too fast"
                self._commit(label, replace(s, results={**s.results, **again}))

    def set_show(self, show: Show | None, inputs: str | None = None) -> None:
        """The planned show (None removes it); ``inputs`` = :meth:`show_inputs` captured when planning began."""
        with self._lock:
            if show is not None and not show.created:
                show = replace(show, created=self._now())
            ins = None if show is None else (inputs or self.show_inputs())
            self._commit("planned show" if show else "remove show", replace(self._state, show=show, show_inputs=ins))
