"""The README's Python API example runs as written: a still target → pose → planned show → played on the emulator."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def api_example() -> str:
    text = README.read_text()
    section = text[text.index("## Python API") :]
    match = re.search(r"```python\n(.*?)```", section, flags=re.S)
    assert match, "the README's Python API section has no python block"
    return match.group(1)


def test_example_is_short():
    code = [line for line in api_example().splitlines() if line.strip()]
    assert len(code) <= 10, code


@pytest.mark.skipif(sys.platform == "win32", reason="the emulator needs POSIX pseudo-terminals")
def test_readme_api_example_runs(tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", api_example()], capture_output=True, text=True, cwd=tmp_path, timeout=600
    )
    assert out.returncode == 0, out.stderr
    iou_loss, collision_free, reason = out.stdout.split()[-3:]
    assert 0 <= float(iou_loss) < 0.6 and collision_free == "True" and reason == "completed", out.stdout
    assert (tmp_path / "o_show.json").is_file()
