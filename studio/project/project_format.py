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
``results`` (keyframe id, pose as joint name → rad, loss components, shadow file, the inputs' fingerprint); ``show``
(file and the inputs' fingerprint); ``mount`` (auto, roll_deg, chosen; the losses auto compared; absent: upright).
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from studio.atomic import write_json, write_with
from studio.imitate.config import LossConfig
from studio.motion.show import Show, load_show, save_show
from studio.project.state import (
    Frame,
    Keyframe,
    Mount,
    NotAProject,
    PoseResult,
    ProjectError,
    ProjectState,
    Source,
    frozen,
    mask_hash,
    text_hash,
)
from studio.sim.roll import file_deg
from studio.targets.images import TargetConfig
from studio.targets.keyframes import KeyframeConfig
from studio.targets.video import VideoConfig

log = logging.getLogger(__name__)

FORMAT_NAME = "shadow-studio-project"
FORMAT_VERSION = 1  # the version this code writes and reads
SUFFIX = ".shadow"  # a project folder's name ends with it
DOC = "project.json"


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


def _show_hash(show: Show) -> str:
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
        "show": None if s.show is None else {"file": f"show-{_show_hash(s.show)[:16]}.json", "inputs": s.show_inputs},
        "mount": {
            "auto": s.mount.auto,
            "roll_deg": file_deg(s.mount.roll),
            "chosen": s.mount.chosen,
            "upright_loss": _num(s.mount.upright_loss),
            "loss": _num(s.mount.loss),
        },
    }


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


def _read_png(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return frozen(np.asarray(im.convert("L")) > 127)


def save_state(folder: Path, state: ProjectState, modified: str) -> None:
    """Write ``state`` into the project ``folder``: new files first, ``project.json`` atomically last, then delete
    the files it no longer names (module doc). A save killed anywhere leaves the previous project readable."""
    folder = Path(folder)
    doc = state_doc(state) | {"modified": modified}
    files = _files(state, doc)
    for name, content in files.items():
        path = folder / name
        if path.exists():  # content-addressed: the same name holds the same content
            continue
        if isinstance(content, Show):
            save_show(content, path)
        else:
            _write_png(path, content)
    write_json(folder / DOC, doc, allow_nan=False)
    remove_unnamed(folder, set(files))


def remove_unnamed(folder: Path, names: set[str]) -> None:
    """Delete the mask, shadow and show files (and left-over temporary files) in ``folder`` not in ``names``."""
    for sub, pattern in (("masks", "*.png"), ("results", "*.png"), (".", "show-*.json")):
        where = folder / sub
        if not where.is_dir():
            continue
        for path in list(where.glob(pattern)) + list(where.glob(".*.tmp")):
            rel = path.relative_to(folder).as_posix()
            if rel not in names:
                try:
                    os.unlink(path)
                except OSError as e:  # another process's file or a read-only folder: harmless, try next time
                    log.debug("could not remove %s: %s", path, e)


def read_doc(folder: Path) -> dict[str, Any]:
    """``project.json`` of ``folder``, its format and version checked (a newer version is refused)."""
    path = Path(folder) / DOC
    if not path.is_file():
        raise NotAProject(f"not a project (no {DOC}): {folder}")
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise ProjectError(f"{path} is not valid JSON ({e}); the folder is damaged") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT_NAME:
        raise ProjectError(f"{path} is not a Shadow Studio project (format {doc.get('format')!r}, not {FORMAT_NAME!r})")
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
        return _from_doc(folder, doc), doc.get("modified", "")
    except ProjectError:
        raise
    except (KeyError, TypeError, ValueError) as e:
        raise ProjectError(f"{folder / DOC} is damaged ({type(e).__name__}: {e})") from None


def _mask(folder: Path, name: str) -> np.ndarray:
    path = folder / name
    if not path.is_file():
        raise ProjectError(f"project file missing: {path}; the project folder is damaged")
    try:
        m = _read_png(path)
    except OSError as e:
        raise ProjectError(f"project file unreadable ({e}): {path}") from None
    if not name.endswith(f"-{mask_hash(m)[:16]}.png"):
        raise ProjectError(f"project file corrupt (its content does not match its name): {path}")
    return m


def _box(v: Any) -> tuple[int, int, int, int] | None:
    return None if v is None else tuple(int(x) for x in v)  # type: ignore[return-value]


def _from_doc(folder: Path, doc: dict[str, Any]) -> ProjectState:
    sources = []
    for d in doc["sources"]:
        first = None if d.get("first_mask") is None else _mask(folder, d["first_mask"])
        d = d | {"frame_box": _box(d.get("frame_box")), "box": _box(d.get("box")), "first_mask": first}
        sources.append(_config(Source, d))
    frames = tuple(Frame(int(f["source"]), int(f["source_frame"]), float(f["time_s"])) for f in doc["frames"])
    settings = doc["settings"]
    video = _config(VideoConfig, settings["video"])
    if frames:
        targets = np.stack([_mask(folder, f["target"]) for f in doc["frames"]])
        auto = np.stack([_mask(folder, f["auto"]) for f in doc["frames"]])
    else:
        targets = auto = np.zeros((0, video.size, video.size), np.uint8)
    targets.flags.writeable = auto.flags.writeable = False
    paint = doc.get("paint", {})
    keyframes = tuple(
        Keyframe(int(k["id"]), int(k["representative"]), tuple(int(m) for m in k["members"]),
                 None if k.get("time_s") is None else float(k["time_s"]), bool(k.get("hold", False)),
                 bool(k.get("edited", False)))
        for k in doc["keyframes"]
    )  # fmt: skip
    results = {}
    for r in doc.get("results", []):
        results[int(r["keyframe"])] = PoseResult(
            pose={n: float(v) for n, v in r["pose"].items()},
            loss={n: _nan(v) for n, v in r["loss"].items()},
            shadow=_mask(folder, r["shadow"]),
            inputs=r["inputs"],
            evaluation={n: _nan(v) for n, v in r.get("evaluation", {}).items()},
            collision_free=bool(r.get("collision_free", True)),
            seconds=float(r.get("seconds", 0.0)),
        )
    show, show_inputs = None, None
    if doc.get("show") is not None:
        path = folder / doc["show"]["file"]
        if not path.is_file():
            raise ProjectError(f"project file missing: {path}; the project folder is damaged")
        show, show_inputs = load_show(path), doc["show"].get("inputs")
        if not doc["show"]["file"].endswith(f"-{_show_hash(show)[:16]}.json"):
            raise ProjectError(f"project file corrupt (its content does not match its name): {path}")
    return ProjectState(
        title=doc.get("title", folder.stem),
        created=doc.get("created", ""),
        sources=tuple(sources),
        video=video,
        still=_config(TargetConfig, settings["still"]),
        clustering=_config(KeyframeConfig, settings["keyframes"]),
        weights=_config(LossConfig, doc["weights"]),
        frames=frames,
        targets=targets,
        auto=auto,
        additions={k: _mask(folder, n) for k, n in paint.get("additions", {}).items()},
        erasures={k: _mask(folder, n) for k, n in paint.get("erasures", {}).items()},
        keyframes=keyframes,
        next_id=int(doc.get("next_keyframe_id", 1 + max((k.id for k in keyframes), default=-1))),
        results=results,
        show=show,
        show_inputs=show_inputs,
        mount=_mount(doc.get("mount")),
    )


def _mount(d: Any) -> Mount:
    """The ``mount`` entry (absent in projects made before it: upright, as their keyframes were optimised)."""
    if not isinstance(d, Mapping):
        return Mount()
    try:
        roll = math.radians(float(d.get("roll_deg", 0.0)))
        loss, upright = d.get("loss"), d.get("upright_loss")
        return Mount(
            auto=bool(d.get("auto", False)), roll=roll, chosen=bool(d.get("chosen", True)),
            upright_loss=None if upright is None else float(upright), loss=None if loss is None else float(loss),
        )  # fmt: skip
    except (TypeError, ValueError):
        raise ProjectError(f"project.json: the mount entry is not understood: {d!r}") from None
