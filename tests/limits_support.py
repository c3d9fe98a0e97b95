"""Helpers of the tests of bounds and refusals (tests/test_limits.py, tests/test_paths.py): the one error line of a
refused command, and a JSON file edited into another."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path


def one_line(proc: subprocess.CompletedProcess, *words: str) -> str:
    """The one error line of a refused command (exit 2, no traceback, no internal error), checked for ``words``."""
    err = proc.stderr.strip()
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    assert err.count("\n") == 0 and "Traceback" not in err and "internal error" not in err, err
    for w in words:
        assert w in err, err
    return err


def edited(path: Path, name: str, change) -> Path:
    doc = json.loads(path.read_text())
    change(doc)
    out = path.with_name(name)
    out.write_text(json.dumps(doc))
    return out
