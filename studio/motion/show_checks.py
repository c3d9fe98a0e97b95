"""Validation of a show document (the parsed JSON of a show file): one clear sentence per problem.

Kept apart from ``studio.motion.show`` (the format and its IO) so the rules read as one list: version, schema, joint
names against the hand, finite values, time starting at 0 and strictly increasing, angles within limits, and
sample-to-sample speed within the velocity limits.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from studio.errors import count
from studio.motion.bounds import (
    MAX_KEYFRAMES,
    MAX_LIMIT,
    MAX_OFFSET_S,
    MAX_RATE_HZ,
    MAX_SAMPLES,
    MAX_SHOW_S,
    MAX_SOURCE_FRAME,
    fmt,
    is_number,
)
from studio.motion.limits import limit_problems
from studio.sim.hand import Hand

FORMAT_NAME = "shadow-studio-show"
READABLE_VERSIONS = (1,)  # versions this code can read
VELOCITY_TOLERANCE = 0.05  # relative slack on the velocity check (finite differences of a planned show never exceed)
LIMIT_TOLERANCE = 1e-6  # rad of slack on the position limits
MAX_SCHEMA_MESSAGES = 8  # schema violations listed before "and N more"


def _jsonschema() -> Any:
    """``jsonschema``, imported without its optional "iri" format checker's package when this process has not
    loaded that package yet: ``rfc3987_syntax`` (which Jupyter's ``jsonschema[format-nongpl]`` installs beside the
    studio) builds a parser for its grammar on import, 1.7 s of the 1.9 s that importing ``jsonschema`` took in
    every process that checked a show. The show schema asks for no format check, and the package stays importable:
    only the name's placeholder is set while ``jsonschema`` loads."""
    import sys

    if "jsonschema" in sys.modules or "rfc3987_syntax" in sys.modules:
        import jsonschema

        return jsonschema
    sys.modules["rfc3987_syntax"] = None  # type: ignore[assignment]  # its import fails; jsonschema goes on without it
    try:
        import jsonschema
    finally:
        del sys.modules["rfc3987_syntax"]
    return jsonschema


def _schema_problems(doc: dict[str, Any], schema: dict[str, Any]) -> list[str]:
    validator = _jsonschema().Draft202012Validator(schema)
    errors = sorted(validator.iter_errors(doc), key=lambda e: [str(p) for p in e.absolute_path])
    out = []
    for e in errors[:MAX_SCHEMA_MESSAGES]:
        where = "/".join(str(p) for p in e.absolute_path) or "top level"
        out.append(f"schema: at {where}: {e.message}")
    if len(errors) > MAX_SCHEMA_MESSAGES:
        out.append(f"schema: and {len(errors) - MAX_SCHEMA_MESSAGES} more violations")
    return out


def _name_problems(names: list[str], hand: Hand) -> list[str]:
    if names == hand.joint_names:
        return []
    unknown = [n for n in names if n not in hand.joint_names]
    missing = [n for n in hand.joint_names if n not in names]
    if unknown or missing:
        return [
            f"joint names do not match the hand: unknown {unknown}, missing {missing}; "
            "the show was made for another hand model"
        ]
    return ["joint names are in a different order than the hand's; re-export the show for this hand"]


def _sample_problems(rows: list[list[float]], names: list[str], limits: dict[str, Any] | None) -> list[str]:
    width = 1 + len(names)
    bad_rows = [i for i, r in enumerate(rows) if len(r) != width]
    if bad_rows:
        return [f"samples {bad_rows[:5]} do not have {width} numbers (time + one angle per joint); the file is damaged"]
    a = np.asarray(rows, dtype=float).reshape(len(rows), width)
    t, q = a[:, 0], a[:, 1:]
    problems = []
    if not np.isfinite(t).all():
        i = int(np.flatnonzero(~np.isfinite(t))[0])
        problems.append(f"sample {i}: time is {t[i]} (NaN/inf); every time must be a finite number of seconds")
    for j in np.flatnonzero(~np.isfinite(q).all(axis=0)):
        i = np.flatnonzero(~np.isfinite(q[:, j]))
        problems.append(f"{names[j]} is NaN/inf at {len(i)} samples (first: sample {i[0]}); the file is damaged")
    if problems:
        return problems
    if t[0] != 0.0:
        problems.append(f"the first sample is at t = {fmt(t[0])} s; a show starts at t = 0")
    if t.max() > MAX_SHOW_S:
        problems.append(f"the show lasts {fmt(t.max())} s; a show lasts at most {fmt(MAX_SHOW_S)} s")
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        i = int(back[0]) + 1
        problems.append(
            f"time goes backwards or repeats at sample {i} (t = {fmt(t[i])} s after {fmt(t[i - 1])} s, "
            f"{count(back.size, 'place')} in all); times must strictly increase"
        )
    if limits is not None and not limit_problems(limits, names):
        lo, hi = np.asarray(limits["lower"]), np.asarray(limits["upper"])
        for j in range(len(names)):
            out = np.flatnonzero((q[:, j] < lo[j] - LIMIT_TOLERANCE) | (q[:, j] > hi[j] + LIMIT_TOLERANCE))
            if out.size:
                i = out[0]
                problems.append(
                    f"{names[j]} leaves its limits [{lo[j]:.4f}, {hi[j]:.4f}] rad at {out.size} samples "
                    f"(first: t = {t[i]:.3f} s, {q[i, j]:.4f} rad)"
                )
        if not back.size and len(t) > 1:
            speed = np.abs(np.diff(q, axis=0)) / np.diff(t)[:, None]
            vmax = np.asarray(limits["velocity"]) * (1 + VELOCITY_TOLERANCE)
            for j in np.flatnonzero((speed > vmax[None]).any(axis=0)):
                i = int(np.argmax(speed[:, j]))
                problems.append(
                    f"{names[j]} moves at {speed[i, j]:.2f} rad/s between t = {t[i]:.3f} and {t[i + 1]:.3f} s, "
                    f"above its velocity limit {limits['velocity'][j]:.2f} rad/s; re-plan the show"
                )
    return problems


def _keyframe_problems(keyframes: list[dict[str, Any]], duration: float | None) -> list[str]:
    if len(keyframes) > MAX_KEYFRAMES:
        return [f"the show has {len(keyframes)} keyframe markers; a show has at most {MAX_KEYFRAMES}"]
    times = [k.get("t") for k in keyframes]
    if not all(is_number(x) and np.isfinite(x) for x in times):
        return ["a keyframe marker has a NaN/inf or missing time"]
    problems = []
    frames = [k.get("source_frame") for k in keyframes]
    if any(f is not None and not (is_number(f) and 0 <= f <= MAX_SOURCE_FRAME) for f in frames):
        problems.append(f"a keyframe marker's source_frame is not a frame index in [0, {MAX_SOURCE_FRAME}]")
    if any(b < a for a, b in zip(times, times[1:])):
        problems.append("keyframe markers are not in time order")
    if duration is not None and any(x < 0 or x > duration + 1e-9 for x in times):
        problems.append(f"a keyframe marker lies outside the show (0 to {duration:.3f} s)")
    return problems


def show_problems(doc: Any, hand: Hand | None = None, schema: dict[str, Any] | None = None) -> list[str]:
    """Every problem of a show document, one sentence each (empty when it is sound).

    ``hand``: the hand to check joint names and position limits against (None: the file's own limits only).
    ``schema``: the JSON Schema to check the structure with (None: skip, for documents built in memory).
    """
    if not isinstance(doc, dict):
        return ["the file is JSON but not a show (expected an object at the top level)"]
    if doc.get("format") != FORMAT_NAME:
        return [f"not a show file (format is {doc.get('format')!r}, expected {FORMAT_NAME!r})"]
    version = doc.get("version")
    if version not in READABLE_VERSIONS:
        newer = isinstance(version, int) and version > max(READABLE_VERSIONS)
        hint = "it was written by a newer Shadow Studio: upgrade" if newer else "re-export the show"
        return [f"unsupported show format version {version!r} (this reader understands {READABLE_VERSIONS}); {hint}"]
    if schema is not None:
        problems = _schema_problems(doc, schema)
        if problems:
            return problems
    problems = []
    names = list(doc["hand"]["joint_names"])
    if hand is not None:
        problems += _name_problems(names, hand)
    rate = doc["rate_hz"]
    if not is_number(rate) or not np.isfinite(rate) or not 0 < rate <= MAX_RATE_HZ:
        shown = fmt(rate) if is_number(rate) else repr(rate)
        problems.append(f"rate_hz is {shown}; it must be a number of Hz in (0, {fmt(MAX_RATE_HZ)}] (servos play 40)")
    limits = doc["limits"]
    lp = limit_problems(limits, names)
    if not lp:
        lp = [
            f"limits.{k} states {fmt(max(limits[k]))}; it must be at most {fmt(MAX_LIMIT)}"
            for k in ("velocity", "acceleration", "jerk")
            if limits[k] and max(limits[k]) > MAX_LIMIT
        ]
    problems += lp
    if hand is not None and not lp and not problems:
        limits = {
            **limits,
            "lower": np.maximum(limits["lower"], hand.lower).tolist(),
            "upper": np.minimum(limits["upper"], hand.upper).tolist(),
        }
    rows = doc["samples"]
    if not rows:
        problems.append("the show has no samples")
        duration = None
    elif len(rows) > MAX_SAMPLES:
        problems.append(f"the show has {len(rows)} samples; a show file holds at most {MAX_SAMPLES}")
        duration = None
    else:
        sp = _sample_problems(rows, names, None if lp else limits)
        problems += sp
        duration = None if sp else float(rows[-1][0])
    problems += _keyframe_problems(doc.get("keyframes", []), duration)
    media = doc.get("media")
    offset = (media or {}).get("offset_s", 0.0)
    if media and not (is_number(offset) and np.isfinite(offset) and abs(offset) <= MAX_OFFSET_S):
        problems.append(f"media.offset_s must be a number of seconds in [-{fmt(MAX_OFFSET_S)}, {fmt(MAX_OFFSET_S)}]")
    return problems
