"""benchmarks/bench_ablation.py end to end at a tiny budget: both models trained, the table and the JSON summary
consistent with each other, a finished checkpoint reused (not retrained) and one with other settings replaced."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "benchmarks" / "bench_ablation.py"
TINY = ["--batch-size", "4", "--eval-size", "16", "--limit", "2", "--search-batch", "4", "--search-iterations", "5"]


def _run(out: Path, targets: Path, steps: int) -> tuple[str, dict]:
    cmd = [sys.executable, str(SCRIPT), "--steps", str(steps), "--out", str(out), "--targets", str(targets), *TINY]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    lines = done.stdout.strip().splitlines()
    return "\n".join(lines[:-1]), json.loads(lines[-1])


@pytest.mark.slow
def test_bench_ablation_tiny(tmp_path, shared_targets):
    out = tmp_path / "ablation"
    table, s = _run(out, shared_targets / "asl", steps=3)
    assert s["models"] == {"fk": "trained", "theta": "trained"}
    assert s["targets"] == 2 and s["steps"] == 3 and 0 <= s["fk_wins"] <= 2
    for inp in ("fk", "theta"):
        assert 0 < s[f"{inp}_test_mae"] < 1 and 0 < s[f"{inp}_total"] and 0 <= s[f"{inp}_iou_loss"] <= 1
    assert s["theta_vs_fk_total"] == pytest.approx(s["theta_total"] / s["fk_total"], abs=2e-3)
    assert s["fk_better_pct_total"] == pytest.approx(100 * (1 - s["fk_total"] / s["theta_total"]), abs=0.2)
    rows = [line for line in table.splitlines() if line.startswith("| ") and "input" not in line]
    assert len(rows) == 2 and f"{s['fk_total']:.3f}" in rows[0] and f"{s['theta_total']:.3f}" in rows[1]

    stamps = {p.name: p.stat().st_mtime_ns for p in out.glob("*.pt")}
    _, again = _run(out, shared_targets / "asl", steps=3)  # same settings: reused, same numbers
    assert again["models"] == {"fk": "reused", "theta": "reused"}
    assert {p.name: p.stat().st_mtime_ns for p in out.glob("*.pt")} == stamps
    assert again["fk_total"] == s["fk_total"] and again["theta_test_mae"] == s["theta_test_mae"]

    _, other = _run(out, shared_targets / "asl", steps=4)  # another budget: both retrained
    assert other["models"] == {"fk": "trained", "theta": "trained"} and other["steps"] == 4
