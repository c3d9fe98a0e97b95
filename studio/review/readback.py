"""Reading a Rerun recording back (``.rrd``): what entities it holds, on which timelines, and scalar series, for
tests and tools that check a review (Rerun 0.41 has no ``rerun.dataframe``: ``rerun.chunk.RrdReader``, DESIGN §6).
Every recording the studio writes has one entity tree and one blueprint: :mod:`studio.review.blueprint`."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("RERUN_NOTEBOOK_ASSET", "inline")  # notebooks must not fetch the viewer from the internet


def read_recording(path: Path) -> dict[str, dict]:
    """Read an ``.rrd`` back: ``{entity_path: {"static": bool, "rows": int, "columns": [...], "timelines": [...],
    "static_columns": [...]}}`` (``static``: its first chunk is; ``static_columns``: those any static chunk holds).

    For tests and tools that check what a recording holds (reads Rerun's own file format).
    """
    import warnings

    from rerun.chunk import RrdReader

    with warnings.catch_warnings():  # a stream saved by `rerun --save` has no footer: read it whole (below)
        warnings.filterwarnings("ignore", message=".*no footer.*")
        reader = RrdReader(str(path))
    try:
        chunks = reader.store().stream()
    except RuntimeError:  # no footer/manifest (a live stream's file): scan the whole file
        chunks = reader.stream()
    out: dict[str, dict] = {}
    for chunk in chunks:
        batch = chunk.to_record_batch()
        entry = out.setdefault(
            chunk.entity_path, {"static": chunk.is_static, "rows": 0, "columns": set(), "timelines": set()}
        )
        entry["rows"] += chunk.num_rows
        entry["columns"] |= set(batch.schema.names)
        entry["timelines"] |= set(chunk.timeline_names)
        entry.setdefault("static_columns", set()).update(batch.schema.names if chunk.is_static else ())
        entry.setdefault("batches", []).append(batch)
    return out


def scalar_series(recording: dict[str, dict], entity: str, timeline: str = "opt_step") -> list[tuple[float, float]]:
    """``(time, value)`` pairs of a ``Scalars`` entity read by :func:`read_recording`: steps (int) on sequence
    timelines, seconds (float) on duration timelines; rows without ``timeline`` are left out."""
    import pyarrow as pa

    values: list[tuple[float, float]] = []
    for batch in recording.get(entity, {}).get("batches", []):
        if timeline not in batch.schema.names or "Scalars:scalars" not in batch.schema.names:
            continue
        column = batch.column(timeline)
        seconds = pa.types.is_duration(column.type)
        times = column.cast(pa.int64()).to_pylist()  # steps, or nanoseconds on a duration timeline
        for t, v in zip(times, batch.column("Scalars:scalars").to_pylist()):
            if t is not None and v is not None:
                values.append((t / 1e9 if seconds else int(t), float(v[0])))
    return sorted(values)


def shown_series(recording: dict[str, dict], path: str, column: str = "Scalars:scalars") -> str | None:
    """The entity of the version of what is logged whole at ``path`` that the viewer shows
    (:mod:`studio.review.series`: version 0 at ``path``, version n at ``PATH/vN``, each hidden by its archetype
    cleared as static data when the next is logged); ``column``: the component that is hidden
    (``"TextLog:text"`` for log lines). None when every version is hidden or none was logged."""
    versions = [path] + sorted((e for e in recording if e.startswith(f"{path}/v") and e[len(path) + 2:].isdigit()),
                               key=lambda e: int(e[len(path) + 2:]))  # fmt: skip
    shown = [e for e in versions if e in recording and column not in recording[e]["static_columns"]]
    return shown[-1] if shown else None


def ordered_rows(recording: dict[str, dict], entity: str, timeline: str) -> list[dict]:
    """Every row of ``entity`` that has ``timeline``, as ``{column: value, "t": time}`` (steps, or nanoseconds on a
    duration timeline), in the order Rerun resolves "the latest row at or before a time": by time, then by row id
    (a time-ordered TUID, big-endian: the row logged last at a time comes last). The chunks of a file read back are
    in no set order, so the order of its batches says nothing about which row was logged last."""
    import pyarrow as pa

    out = []
    for batch in recording.get(entity, {}).get("batches", []):
        if timeline not in batch.schema.names:
            continue
        columns = {n: batch.column(n).to_pylist() for n in batch.schema.names if n != timeline}
        times = batch.column(timeline).cast(pa.int64()).to_pylist()
        out += [{"t": t, **{n: v[i] for n, v in columns.items()}} for i, t in enumerate(times) if t is not None]
    return sorted(out, key=lambda r: (r["t"], r["rerun.controls.RowId"]))
