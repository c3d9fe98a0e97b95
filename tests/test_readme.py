"""The README's Python API examples run as written: a still target → pose → planned show → played on the emulator;
a video → a one-source project → its show, run again with nothing recomputed."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def api_examples() -> list[str]:
    text = README.read_text()
    section = text[text.index("## Python API") :]
    section = section[: section.index("\n## ", 4)]
    blocks = re.findall(r"```python\n(.*?)```", section, flags=re.S)
    assert len(blocks) == 2, "the README's Python API section has a still and a video example"
    return blocks


def api_example() -> str:
    return api_examples()[0]


def test_example_is_short():
    code = [line for line in api_example().splitlines() if line.strip()]
    assert len(code) <= 10, code


@pytest.mark.slow
@pytest.mark.skipif(sys.platform == "win32", reason="the emulator needs POSIX pseudo-terminals")
def test_readme_api_example_runs(tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", api_example()], capture_output=True, text=True, cwd=tmp_path, timeout=600
    )
    assert out.returncode == 0, out.stderr
    iou_loss, collision_free, reason = out.stdout.split()[-3:]
    assert 0 <= float(iou_loss) < 0.6 and collision_free == "True" and reason == "completed", out.stdout
    assert (tmp_path / "o_show.json").is_file()


@pytest.mark.slow
def test_readme_video_example_runs(tmp_path):
    out = subprocess.run(
        [sys.executable, "-c", api_examples()[1]], capture_output=True, text=True, cwd=tmp_path, timeout=900
    )
    assert out.returncode == 0, out.stderr
    first, second = out.stdout.strip().splitlines()[-2:]
    duration, n = first.split()[:2]
    assert float(duration) > 1.0 and int(n) >= 2 and "'show.json'" in first and "'keyframes.json'" in first, out.stdout
    assert second.startswith("[]") and second.endswith("]") and second != "[] []", second  # all skipped
    assert (tmp_path / "horse" / "muybridge_horse.shadow" / "project.json").is_file()
