"""Writing evaluation tables: Markdown with notes, CSV, settings JSON (shared by Table 1 and Table 2).

Conventions (one place for both tables): a value not computed is NaN in the engine, ``None`` in JSON-able rows,
``n/a`` in Markdown and an empty cell in CSV; losses are shown with 3 decimals, counts and percentages as given by
the caller's ``digits``. Files go through :mod:`studio.atomic` (a table is never half written).
"""

from __future__ import annotations

import csv
import io
import json
import math
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

from studio.atomic import write_text


def nan_to_none(x):
    """A number for JSON: NaN (a term not computed) → None; anything else as it is."""
    return None if x is None or (isinstance(x, float) and math.isnan(x)) else x


def fmt(x, digits: int = 3) -> str:
    """A Markdown cell: ``n/a`` for None/NaN, a float with ``digits`` decimals, anything else as text."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    return f"{x:.{digits}f}" if isinstance(x, float) else str(x)


def markdown_table(
    label: str,
    rows: Sequence[Mapping],
    columns: Mapping[str, str],
    label_key: str,
    digits: Mapping[str, int] | None = None,
    best: str | None = "total",
    notes: Sequence[str] = (),
) -> str:
    """``rows`` as a Markdown table: first column ``label`` (each row's ``label_key``), then ``columns`` (header →
    row key, formatted by :func:`fmt` with ``digits[key]``, default 3); the lowest ``best`` value in bold; then the
    notes as a list."""
    digits = digits or {}
    values = [r[best] for r in rows if best and r.get(best) is not None and not math.isnan(r[best])]
    lowest = min(values) if values else None
    lines = [f"| {label} | " + " | ".join(columns) + " |", "|---|" + "---:|" * len(columns)]
    for r in rows:
        cells = [fmt(r.get(key), digits.get(key, 3)) for key in columns.values()]
        if lowest is not None and r.get(best) == lowest:
            i = list(columns.values()).index(best)
            cells[i] = f"**{cells[i]}**"
        lines.append(f"| {r[label_key]} | " + " | ".join(cells) + " |")
    return "\n".join(lines + [""] + [f"- {n}" for n in notes]) + "\n"


def csv_text(keys: Sequence[str], rows: Iterable[Mapping]) -> str:
    """CSV with header ``keys`` (other keys of a row ignored); None and NaN become empty cells."""
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=list(keys), extrasaction="ignore")
    w.writeheader()
    w.writerows({k: "" if nan_to_none(r.get(k)) is None else r[k] for k in keys} for r in rows)
    return buf.getvalue()


def write_report(out: Path, texts: Mapping[str, tuple[str, str]], settings: Mapping) -> dict[str, str]:
    """Write ``texts`` (name → (file name, contents)) and ``settings.json`` into the folder ``out`` (made when
    missing); returns name → path, ``"settings"`` included."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, (file_name, text) in texts.items():
        paths[name] = out / file_name
        write_text(paths[name], text)
    paths["settings"] = out / "settings.json"
    write_text(paths["settings"], json.dumps(settings, indent=2, default=str))
    return {k: str(v) for k, v in paths.items()}
