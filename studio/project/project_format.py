"""The project folder format: ``NAME.shadow/`` with ``project.json`` and the files it names (DESIGN §4).

Layout (version 1)::

    NAME.shadow/
      project.json                      {"format": "shadow-studio-project", "version": 1, ...} (below)
      masks/target-S-FFFFF-H.png        each sampled frame's shadow mask (source S, source frame F)
      masks/auto-S-FFFFF-H.png          its automatic expressive mask (moving ∪ holes)
      masks/add-S-FFFFF-H.png           the artist's painted additions of that frame, when any
      masks/erase-S-FFFFF-H.png         … and painted erasures, apart, so strokes survive a re-run
      masks/first-S-H.png               a colour source's first-frame segmentation mask, when given
      results/shadow-kK-H.png           keyframe K's rendered shadow
      show-H.json                       the planned show (studio.motion.show's format)

``H`` is the start of the content's sha256, so a file's name changes whenever its content does. A save writes the
files that are new (atomically, :mod:`studio.atomic`), then ``project.json`` atomically last, then deletes the files
no longer named: a save killed at any point leaves the previous project complete and readable. PNG masks are 0/255
greys read back as uint8 {0, 1}, bit for bit. Floats are written with Python's round-trip repr; a NaN loss
component is written as ``null``.

``project.json``: ``title``, ``created``, ``modified``; ``sources`` (path as given, absolute path, sha256, kind,
what loading found: fps, duration, footage kind, square frame; segmentation box or first mask); ``settings``
(``video``: VideoConfig, ``still``: TargetConfig, ``keyframes``: KeyframeConfig); ``weights`` (LossConfig);
``frames`` (source, source frame, source time, target and auto mask files); ``paint`` (additions and erasures by
frame key ``"S:F"``); ``keyframes`` (id, representative frame, member frames, time override, hold, edited);
``results`` (keyframe id, pose as joint name → rad, loss components, shadow file, the inputs' fingerprint, what a
stopped run still owes it: ``awaits`` "together" or "again", absent or "": nothing); ``show``
(file and the inputs' fingerprint); ``mount`` (auto, roll_deg, chosen; the losses auto compared; ``apart``: the
keyframes it casts clearly worse than a roll of their own would; absent: upright).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import re
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from studio.atomic import write_json, write_with
from studio.motion.show import Show, save_show
from studio.project.containment import NAME, SUBFOLDERS, check_name, check_subfolders, regular_file
from studio.project.state import Frame, MountApart, ProjectState, mask_hash, text_hash
from studio.sim.roll import file_deg

log = logging.getLogger(__name__)

FORMAT_NAME = "shadow-studio-project"
FORMAT_VERSION = 1  # the version this code writes and reads
SUFFIX = ".shadow"  # a project folder's name ends with it
DOC = "project.json"
TEMP = re.compile(r"\..+\.[0-9a-f]{8,}\.tmp")  # the atomic writer's temporary files (studio.atomic)


def _mask_name(kind: str, owner: str, mask: np.ndarray) -> str:
    return f"masks/{kind}-{owner}-{mask_hash(mask)[:16]}.png"


def _key_frame(key: str) -> Frame:
    """The frame named by a key ``"S:F"`` (its time unknown: 0)."""
    source, frame = key.split(":")
    return Frame(int(source), int(frame), 0.0)


def _frame_owner(f: Frame) -> str:
    return f"{f.source}-{f.source_frame:05d}"


def _num(x: float) -> float | None:
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else float(x)


def _nan(x: float | None) -> float:
    return math.nan if x is None else float(x)


def _config(cls: type, d: Mapping[str, Any]) -> Any:
    known = {f.name for f in dataclasses.fields(cls)}
    extra = set(d) - known
    if extra:
        log.warning("%s: ignoring unknown settings %s", cls.__name__, sorted(extra))
    return cls(**{k: v for k, v in d.items() if k in known})


def show_hash(show: Show) -> str:
    return text_hash(show.to_dict())


def state_doc(s: ProjectState) -> dict[str, Any]:
    """The ``project.json`` document of state ``s`` (module doc), without ``modified``."""
    sources = []
    for i, src in enumerate(s.sources):
        d = dataclasses.asdict(dataclasses.replace(src, first_mask=None))
        d["first_mask"] = None if src.first_mask is None else _mask_name("first", str(i), src.first_mask)
        sources.append(d)
    results = []
    for k, r in sorted(s.results.items()):
        results.append({
            "keyframe": k, "pose": {n: float(v) for n, v in r.pose.items()},
            "loss": {n: _num(v) for n, v in r.loss.items()},
            "evaluation": {n: _num(v) for n, v in r.evaluation.items()},
            "shadow": f"results/shadow-k{k}-{mask_hash(r.shadow)[:16]}.png", "inputs": r.inputs,
            "collision_free": bool(r.collision_free), "seconds": float(r.seconds),
            "awaits": r.awaits,
        })  # fmt: skip
    keys = {f.key: f for f in s.frames}
    owner = {k: _frame_owner(keys.get(k) or _key_frame(k)) for k in (*s.additions, *s.erasures)}
    return {
        "format": FORMAT_NAME,
        "version": FORMAT_VERSION,
        "title": s.title,
        "created": s.created,
        "sources": sources,
        "settings": {
            "video": dataclasses.asdict(s.video),
            "still": dataclasses.asdict(s.still),
            "keyframes": dataclasses.asdict(s.clustering),
        },
        "weights": dataclasses.asdict(s.weights),
        "frames": [
            {
                "source": f.source,
                "source_frame": f.source_frame,
                "time_s": float(f.time_s),
                "target": _mask_name("target", _frame_owner(f), s.targets[i]),
                "auto": _mask_name("auto", _frame_owner(f), s.auto[i]),
            }
            for i, f in enumerate(s.frames)
        ],  # fmt: skip
        "paint": {
            "additions": {k: _mask_name("add", owner[k], m) for k, m in sorted(s.additions.items())},
            "erasures": {k: _mask_name("erase", owner[k], m) for k, m in sorted(s.erasures.items())},
        },
        "keyframes": [dataclasses.asdict(kf) | {"members": list(kf.members)} for kf in s.keyframes],
        "next_keyframe_id": s.next_id,
        "results": results,
        "show": None if s.show is None else {"file": f"show-{show_hash(s.show)[:16]}.json", "inputs": s.show_inputs},
        "mount": {
            "auto": s.mount.auto,
            "roll_deg": file_deg(s.mount.roll),
            "chosen": s.mount.chosen,
            "upright_loss": _num(s.mount.upright_loss),
            "loss": _num(s.mount.loss),
        }
        | ({"apart": [_apart(a) for a in s.mount.apart]} if s.mount.apart else {}),  # written when some are named
    }


def _apart(a: MountApart) -> dict[str, Any]:
    """One keyframe the mount's roll casts clearly worse (:class:`~studio.project.state.MountApart`) as written."""
    return {"keyframe": a.keyframe, "frame": a.frame, "loss": a.loss, "own_roll_deg": file_deg(a.own_roll),
            "own_loss": a.own_loss}  # fmt: skip


def _files(s: ProjectState, doc: dict[str, Any]) -> dict[str, np.ndarray | Show]:
    """Relative file name → the mask or show it holds, for every file ``doc`` names."""
    out: dict[str, np.ndarray | Show] = {}
    for i, src in enumerate(s.sources):
        if src.first_mask is not None:
            out[doc["sources"][i]["first_mask"]] = src.first_mask
    for i, f in enumerate(doc["frames"]):
        out[f["target"]], out[f["auto"]] = s.targets[i], s.auto[i]
    for layer, masks in (("additions", s.additions), ("erasures", s.erasures)):
        for k, name in doc["paint"][layer].items():
            out[name] = masks[k]
    for r in doc["results"]:
        out[r["shadow"]] = s.results[r["keyframe"]].shadow
    if s.show is not None:
        out[doc["show"]["file"]] = s.show
    return out


def _write_png(path: Path, mask: np.ndarray) -> None:
    image = Image.fromarray((np.asarray(mask) != 0).astype(np.uint8) * 255, mode="L")
    write_with(path, lambda f: image.save(f, format="PNG"))


def save_state(folder: Path, state: ProjectState, modified: str) -> None:
    """Write ``state`` into the project ``folder``: new files first, ``project.json`` atomically last, then delete
    the project files it no longer names (module doc; only files of the shapes a save makes, never another
    file). A save killed anywhere leaves the previous project readable. The caller holds the project's write lock
    (:mod:`studio.project.lock`), so no other writer's new files can be there."""
    folder = Path(folder)
    check_subfolders(folder)
    doc = state_doc(state) | {"modified": modified}
    files = _files(state, doc)
    for name, content in files.items():
        path = check_name(folder, name)
        if regular_file(path):  # content-addressed: the same name holds the same content
            continue
        if isinstance(content, Show):
            save_show(content, path)
        else:
            _write_png(path, content)
    write_json(folder / DOC, doc, allow_nan=False)
    remove_unnamed(folder, set(files))


def remove_unnamed(folder: Path, names: set[str]) -> None:
    """Delete the project files (of the shapes a save makes, regular files only) not in ``names``, and the atomic
    writer's left-over temporary files, in the project folder and its own subfolders (a save killed midway)."""
    paths = []
    for sub in (".", *SUBFOLDERS):
        where = folder / sub
        if not where.is_dir() or where.is_symlink():
            continue
        for path in where.iterdir():
            rel = path.relative_to(folder).as_posix()
            if (TEMP.fullmatch(path.name) or (NAME.fullmatch(rel) and rel not in names)) and regular_file(path):
                paths.append(path)
    for path in paths:
        try:
            os.unlink(path)
        except OSError as e:  # a read-only folder: harmless, the file is simply kept
            log.debug("could not remove %s: %s", path, e)
