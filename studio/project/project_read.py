"""Reading ``project.json`` and the files it names back into a :class:`ProjectState`, trusting nothing in it.

The format is :mod:`studio.project.project_format`'s. A project folder may come from anywhere (an archive, a
colleague, a hand edit), so every entry is checked before it is used, and anything wrong is one
:class:`ProjectError` naming the entry (never a ``KeyError`` or an ``IndexError`` later): JSON nested beyond
reason, settings and weights that are not numbers of their kind (``"abc"``, NaN, a string ``"false"`` for a
yes/no), frames that name a source the project lacks, keyframes with duplicate ids or members that are not frames,
results for keyframes that do not exist, file names outside the project (:mod:`studio.project.containment`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from studio.atomic import JsonFileError, read_json
from studio.errors import count, plural
from studio.imitate.config import LossConfig
from studio.motion.bounds import MAX_SHOW_S, number_problem
from studio.motion.show import load_show
from studio.project.containment import check_name, check_subfolders, regular_file
from studio.project.project_format import DOC, FORMAT_NAME, FORMAT_VERSION, show_hash
from studio.project.state import (
    AWAITS,
    Frame,
    Keyframe,
    Mount,
    MountApart,
    NotAProject,
    PoseResult,
    ProjectError,
    ProjectState,
    Source,
    frozen,
    mask_hash,
)
from studio.targets.images import TargetConfig
from studio.targets.keyframes import KeyframeConfig
from studio.targets.video import VideoConfig

MAX_DOC_BYTES = 64 << 20  # a project.json larger than this is not one this studio wrote (≈ 100,000 frames)


class Damaged(ProjectError):
    """``project.json`` holds an entry this studio cannot use (hand-edited, truncated or not from this studio)."""


def read_doc(folder: Path) -> dict[str, Any]:
    """``project.json`` of ``folder``, its format and version checked (a newer version is refused)."""
    path = Path(folder) / DOC
    if not Path(folder).is_dir():
        raise NotAProject.at(Path(folder))
    if not path.is_file():
        raise NotAProject(f"not a project (no {DOC}): {folder}")
    check_subfolders(folder)
    try:
        doc = read_json(path, MAX_DOC_BYTES, "project file")
    except JsonFileError as e:
        raise ProjectError(f"{e}; the project folder is damaged") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT_NAME:
        found = doc.get("format") if isinstance(doc, dict) else type(doc).__name__
        raise ProjectError(f"{path} is not a Shadow Studio project (format {found!r}, not {FORMAT_NAME!r})")
    version = doc.get("version")
    if not isinstance(version, int) or version < 1:
        raise ProjectError(f"{path} has no valid format version ({version!r})")
    if version > FORMAT_VERSION:
        raise ProjectError(
            f"{path} is project format version {version}, newer than version {FORMAT_VERSION} that this "
            "Shadow Studio reads; update Shadow Studio to open it"
        )
    return doc


def load_state(folder: Path) -> tuple[ProjectState, str]:
    """The state saved in ``folder`` and its ``modified`` time; every named file must exist and match its hash."""
    folder = Path(folder)
    doc = read_doc(folder)
    try:
        return _from_doc(folder, doc), str(doc.get("modified", ""))
    except ProjectError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError, IndexError) as e:
        raise Damaged(f"{folder / DOC} is damaged ({type(e).__name__}: {e})") from None


def _mask(folder: Path, name: Any) -> np.ndarray:
    path = check_name(folder, name)
    if not regular_file(path):
        what = "is a symbolic link, not a file" if path.is_symlink() else "is missing"
        raise ProjectError(f"project file {what}: {path}; the project folder is damaged")
    try:
        with Image.open(path) as im:
            m = frozen(np.asarray(im.convert("L")) > 127)
    except (OSError, Image.DecompressionBombError) as e:
        raise ProjectError(f"project file unreadable ({e}): {path}") from None
    if not name.endswith(f"-{mask_hash(m)[:16]}.png"):
        raise ProjectError(f"project file corrupt (its content does not match its name): {path}")
    return m


def _box(v: Any) -> tuple[int, int, int, int] | None:
    return None if v is None else tuple(int(x) for x in v)  # type: ignore[return-value]


def _nan(x: float | None) -> float:
    return math.nan if x is None else float(x)


def _kinds(annotation: Any) -> tuple[set[type], bool]:
    """The JSON value types a field of this annotation takes, and whether it may be null."""
    args = typing.get_args(annotation) if isinstance(annotation, types.UnionType) else (annotation,)
    optional = type(None) in args
    kinds = {a for a in args if a in (bool, int, float, str)}
    return kinds, optional


def typed_config(cls: type, d: Any, where: str) -> Any:
    """``cls(**d)`` for a settings entry, every field checked to be a value of its declared kind (a yes/no is a
    JSON true/false, a number is a finite number, never a string); unknown fields are ignored."""
    if not isinstance(d, Mapping):
        raise Damaged(f"{where}: expected an object of settings, found {type(d).__name__}")
    hints = typing.get_type_hints(cls)
    values = {}
    for f in dataclasses.fields(cls):
        if f.name not in d:
            continue
        v, (kinds, optional) = d[f.name], _kinds(hints[f.name])
        ok = (v is None and optional) or not kinds  # a field of another kind (a tuple…) is checked by cls itself
        if bool in kinds:
            ok = ok or isinstance(v, bool)
        if float in kinds:
            ok = ok or (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v))
        elif int in kinds:
            ok = ok or (isinstance(v, int) and not isinstance(v, bool))
        if str in kinds:
            ok = ok or isinstance(v, str)
        if not ok:
            want = " or ".join(sorted(k.__name__ for k in kinds)) + (" or null" if optional else "")
            raise Damaged(f"{where}.{f.name} must be a finite {want}, not {json.dumps(v)[:60]}")
        values[f.name] = v
    try:
        return cls(**values)
    except (TypeError, ValueError) as e:
        raise Damaged(f"{where}: {e}") from None


def _index(v: Any, n: int, what: str) -> int:
    if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v < n:
        raise Damaged(f"{DOC}: {what} {json.dumps(v)[:40]} is not one of the project's {n} (0 to {n - 1})")
    return v


def _keyframes(doc: dict, n_frames: int) -> tuple[Keyframe, ...]:
    out, seen_ids, seen_frames = [], set(), set()
    for k in doc["keyframes"]:
        kid = k["id"]
        if not isinstance(kid, int) or isinstance(kid, bool) or kid < 0 or kid in seen_ids:
            raise Damaged(f"{DOC}: keyframe id {json.dumps(kid)[:40]} is not a new non-negative whole number")
        seen_ids.add(kid)
        members = tuple(_index(m, n_frames, f"keyframe {kid}'s member frame") for m in k["members"])
        if not members or seen_frames & set(members):
            raise Damaged(f"{DOC}: keyframe {kid} has no member frames, or shares one with another keyframe")
        seen_frames |= set(members)
        t = k.get("time_s")
        if t is not None and (number_problem("t", t, 0.0, MAX_SHOW_S) is not None):
            raise Damaged(f"{DOC}: keyframe {kid}'s time must be a number of seconds in [0, {MAX_SHOW_S:g}] or null, "
                          f"not {json.dumps(t)[:40]}")  # fmt: skip
        flags = {name: k.get(name, False) for name in ("hold", "edited")}
        if not all(isinstance(v, bool) for v in flags.values()):
            raise Damaged(f"{DOC}: keyframe {kid}'s hold and edited must be true or false, not {flags}")
        rep = _index(k["representative"], n_frames, f"keyframe {kid}'s representative frame")
        if rep not in members:
            raise Damaged(f"{DOC}: keyframe {kid}'s representative frame {rep} is not one of its members")
        out.append(Keyframe(kid, rep, tuple(sorted(members)), None if t is None else float(t), **flags))
    if n_frames and not out:
        raise Damaged(f"{DOC}: the project has {count(n_frames, 'frame')} but no keyframe; every frame belongs to one")
    alone = sorted(set(range(n_frames)) - seen_frames)
    if n := len(alone):
        raise Damaged(f"{DOC}: {plural('frame', n)} {alone[:10]} {plural('belongs', n)} to no keyframe")
    return tuple(out)


def _result(folder: Path, r: dict, ids: set[int]) -> tuple[int, PoseResult]:
    k = r["keyframe"]
    if k not in ids or isinstance(k, bool):
        raise Damaged(f"{DOC}: a result is for keyframe {json.dumps(k)[:40]}, which the project does not have")
    pose = {str(n): float(v) for n, v in r["pose"].items()}
    if not all(math.isfinite(v) for v in pose.values()):
        raise Damaged(f"{DOC}: keyframe {k}'s pose has a joint angle that is not a finite number")
    return k, PoseResult(
        pose=pose, loss={n: _nan(v) for n, v in r["loss"].items()}, shadow=_mask(folder, r["shadow"]),
        inputs=str(r["inputs"]), evaluation={n: _nan(v) for n, v in r.get("evaluation", {}).items()},
        collision_free=bool(r.get("collision_free", True)), seconds=float(r.get("seconds", 0.0)),
        awaits=_awaits(k, r.get("awaits", "")),
    )  # fmt: skip


def _awaits(k: int, value: Any) -> str:
    if value != "" and value not in AWAITS:
        raise Damaged(f"{DOC}: keyframe {k}'s result awaits {json.dumps(value)[:40]}, not one of {sorted(AWAITS)}")
    return value


def _from_doc(folder: Path, doc: dict[str, Any]) -> ProjectState:
    sources = []
    for i, d in enumerate(doc["sources"]):
        first = None if d.get("first_mask") is None else _mask(folder, d["first_mask"])
        d = d | {"frame_box": _box(d.get("frame_box")), "box": _box(d.get("box")), "first_mask": first}
        sources.append(typed_config(Source, d, f"{DOC}: sources[{i}]"))
    frames = tuple(
        Frame(_index(f["source"], len(sources), "a frame's source"), int(f["source_frame"]), float(f["time_s"]))
        for f in doc["frames"]
    )
    settings = doc["settings"]
    video = typed_config(VideoConfig, settings["video"], f"{DOC}: settings.video")
    if frames:
        targets = np.stack([_mask(folder, f["target"]) for f in doc["frames"]])
        auto = np.stack([_mask(folder, f["auto"]) for f in doc["frames"]])
    else:
        targets = auto = np.zeros((0, video.size, video.size), np.uint8)
    if targets.shape[1:] != (video.size, video.size) or auto.shape != targets.shape:
        raise Damaged(f"{DOC}: the frames' masks are not {video.size} × {video.size} pixels as the settings say")
    targets.flags.writeable = auto.flags.writeable = False
    paint = doc.get("paint", {})
    keyframes = _keyframes(doc, len(frames))
    ids = {kf.id for kf in keyframes}
    results = dict(_result(folder, r, ids) for r in doc.get("results", []))
    show, show_inputs = None, None
    if doc.get("show") is not None:
        path = check_name(folder, doc["show"]["file"])
        if not regular_file(path):
            raise ProjectError(f"project file missing (or a symbolic link): {path}; the project folder is damaged")
        show, show_inputs = load_show(path), doc["show"].get("inputs")
        if not doc["show"]["file"].endswith(f"-{show_hash(show)[:16]}.json"):
            raise ProjectError(f"project file corrupt (its content does not match its name): {path}")
    next_id = doc.get("next_keyframe_id", 1 + max(ids, default=-1))
    if not isinstance(next_id, int) or next_id <= max(ids, default=-1):
        raise Damaged(f"{DOC}: next_keyframe_id {next_id!r} must be a whole number above every keyframe id")
    return ProjectState(
        title=str(doc.get("title", folder.stem)),
        created=str(doc.get("created", "")),
        sources=tuple(sources),
        video=video,
        still=_still(settings["still"]),
        clustering=typed_config(KeyframeConfig, settings["keyframes"], f"{DOC}: settings.keyframes"),
        weights=typed_config(LossConfig, doc["weights"], f"{DOC}: weights"),
        frames=frames,
        targets=targets,
        auto=auto,
        additions={str(k): _mask(folder, n) for k, n in paint.get("additions", {}).items()},
        erasures={str(k): _mask(folder, n) for k, n in paint.get("erasures", {}).items()},
        keyframes=keyframes,
        next_id=next_id,
        results=results,
        show=show,
        show_inputs=show_inputs,
        mount=_mount(doc.get("mount")),
    )


def _still(d: Any) -> TargetConfig:
    """The still settings; saved before the loader filled crease pockets, they lack ``pocket_reach``: 0 (off)."""
    old = {"pocket_reach": 0.0} if isinstance(d, Mapping) and "pocket_reach" not in d else {}
    return typed_config(TargetConfig, old | d, f"{DOC}: settings.still")


def _apart(d: Any) -> MountApart:
    """One entry of the mount's ``apart`` list (a ValueError when it is not one)."""
    ok = isinstance(d, Mapping) and all(type(d.get(k)) is int and d[k] >= 0 for k in ("keyframe", "frame"))
    loss, deg, own = (float(d.get(k)) if ok else math.nan for k in ("loss", "own_roll_deg", "own_loss"))
    if not all(math.isfinite(v) for v in (loss, deg, own)):
        raise ValueError
    return MountApart(d["keyframe"], d["frame"], loss, math.radians(deg), own)


def _mount(d: Any) -> Mount:
    """The ``mount`` entry (absent in projects made before it: upright, as their keyframes were optimised)."""
    if not isinstance(d, Mapping):
        return Mount()
    try:
        roll = math.radians(float(d.get("roll_deg", 0.0)))
        loss, upright = d.get("loss"), d.get("upright_loss")
        if not math.isfinite(roll) or not all(isinstance(d.get(k, False), bool) for k in ("auto", "chosen")):
            raise ValueError
        return Mount(
            auto=bool(d.get("auto", False)), roll=roll, chosen=bool(d.get("chosen", True)),
            upright_loss=None if upright is None else float(upright), loss=None if loss is None else float(loss),
            apart=tuple(_apart(a) for a in d.get("apart", [])),
        )  # fmt: skip
    except (TypeError, ValueError):
        raise Damaged(f"{DOC}: the mount entry is not understood: {json.dumps(d)[:80]}") from None
