"""Table 2 (the video ablation): six rows, every column, one measure for every row, NaN handling, transition counts
that add up, cancel, sequence gathering, and `evaluate-video` end to end on a short DAVIS sequence."""

from __future__ import annotations

import csv
import json
import math
import threading
from dataclasses import replace

import numpy as np
import pytest
import torch

from studio.cli.main import build_parser, main
from studio.cli.run_flags import sequence_from_args
from studio.errors import TargetError
from studio.evaluate.sequences import gather_sequences, sequence_from_masks
from studio.evaluate.table1 import LOSS_COLUMNS
from studio.evaluate.table2 import (
    EXTRA_COLUMNS,
    PAPER_ROWS,
    ROWS,
    STUDIO_ROW,
    VideoEvaluator,
    summarise,
    to_markdown,
    write_table,
)
from studio.imitate.config import CPU_SEQUENCE, PAPER_SEQUENCE, LossConfig, RefineConfig, SearchConfig, SequenceConfig
from studio.imitate.sequence import SequenceImitator
from studio.imitate.still import DEFAULT_MODEL
from studio.learn.selfmodel import load_selfmodel
from studio.sim.physics import CollisionWorld
from studio.sim.sampling import sample_poses
from studio.targets.keyframes import KeyframeConfig

TINY = SequenceConfig(
    first=SearchConfig(batch=8, iterations=15, lr=0.08),
    next=SearchConfig(batch=4, iterations=8, lr=0.08),
    refine=RefineConfig(restarts=2, steps=15),
    candidates=1,
)
TINY_FLAGS = ["--search-batch", "8", "--search-iterations", "15", "--next-batch", "4", "--next-iterations", "8",
              "--refine-steps", "15", "--refine-restarts", "2", "--candidates", "1",
              "--sweep-draws", "96", "--sweep-passes", "1", "--joint-generations", "10"]  # fmt: skip


def test_rows_are_the_papers_six_and_the_studios():
    assert [r.name for r in PAPER_ROWS] == [
        "Independent Base", "Independent +Exp", "Independent +Exp+Temp",
        "Sequential Base", "Sequential +Exp", "Sequential +Exp+Temp",
    ]  # fmt: skip
    assert [(r.mode, r.expressive, r.temporal) for r in PAPER_ROWS[3:]] == [
        ("sequential", False, False), ("sequential", True, False), ("sequential", True, True)
    ]  # fmt: skip
    cfg = ROWS[2].config(CPU_SEQUENCE)
    assert (cfg.mode, cfg.expressive, cfg.temporal, cfg.first) == ("independent", True, True, CPU_SEQUENCE.first)
    assert not any(r.clock or r.roll for r in PAPER_ROWS) and not cfg.keep_clock  # the paper's method as it was
    assert ROWS == (*PAPER_ROWS, STUDIO_ROW) and STUDIO_ROW.config(CPU_SEQUENCE).keep_clock and STUDIO_ROW.roll


def test_summary_nan_handling_and_sums():
    """Means skip a term not computed (NaN/None), n/a where no keyframe has it; transitions are summed."""
    nan = math.nan
    row = ROWS[0].name

    def kf(seq, k, exp_iou):
        return {"sequence": seq, "row": row, "keyframe": k, "total": 0.2 + k, "base": 0.1, "clip": nan, "mae": 0.1,
                "iou_loss": 0.2, "exp_iou": exp_iou, "exp_clip": nan, "expr": exp_iou, "temporal": nan,
                "collision_free": k != 1}  # fmt: skip

    keyframes = [kf("a", 0, 0.5), kf("a", 1, nan), kf("a", 2, 0.3), kf("b", 0, nan)]
    records = [
        {"sequence": "a", "row": row, "success": 1, "transitions": 2, "success_image": 0, "mean_steps": [0.1, 0.5],
         "seconds": 4.0},
        {"sequence": "b", "row": row, "success": 0, "transitions": 0, "success_image": 0, "mean_steps": [],
         "seconds": 2.0},
    ]  # fmt: skip
    (s,) = summarise(records, keyframes)
    assert s["exp_iou"] == pytest.approx(0.4) and s["clip"] is None and s["exp_clip"] is None
    assert s["total"] == pytest.approx(np.mean([0.2, 1.2, 2.2, 0.2]))
    assert (s["success"], s["transitions"], s["transitions_text"]) == (1, 2, "1/2")
    assert s["success_pct"] == pytest.approx(50.0) and s["mean_step"] == pytest.approx(0.3)
    assert (s["in_collision"], s["seconds"], s["sequences"], s["keyframes"]) == (1, 3.0, 2, 4)
    md = to_markdown([s], ["a note"])
    assert "| Independent Base | **0.950** | 0.100 | n/a |" in md and "| 1/2 | 50.0 |" in md and "- a note" in md
    records[0]["transitions"] = records[0]["success"] = 0
    assert summarise(records, keyframes)[0]["success_pct"] is None  # no transition at all: n/a, not 0 % or 100 %


def test_gather_sequences(tmp_path):
    for name in ("b_seq", "a_seq"):
        (tmp_path / "set" / name).mkdir(parents=True)
        (tmp_path / "set" / name / "00000.png").write_bytes(b"")
    (tmp_path / "set" / "clip.gif").write_bytes(b"")
    (tmp_path / "set" / "README.md").write_text("not a sequence")
    got = gather_sequences([tmp_path / "set", tmp_path / "set" / "a_seq"])
    assert [p.name for p in got] == ["a_seq", "b_seq", "clip.gif", "a_seq"]  # a frame folder is one sequence
    (tmp_path / "empty").mkdir()
    with pytest.raises(TargetError, match="no sequences in"):
        gather_sequences([tmp_path / "empty"])
    with pytest.raises(TargetError, match="not found"):
        gather_sequences([tmp_path / "nowhere"])


def test_preset_and_budget_flags():
    parse = build_parser().parse_args
    cfg = sequence_from_args(parse(["evaluate-video", "x", "--out", "o"]))
    assert cfg == CPU_SEQUENCE
    cfg = sequence_from_args(parse(["evaluate-video", "x", "--out", "o", "--preset", "paper",
                                    "--search-batch", "8", "--candidates", "2", "--seed", "3"]))  # fmt: skip
    assert (cfg.first.batch, cfg.first.iterations, cfg.first.seed) == (8, 3000, 3)  # only given fields change
    assert cfg.next == replace(PAPER_SEQUENCE.next, seed=3)
    assert cfg.refine.steps == PAPER_SEQUENCE.refine.steps and cfg.candidates == 2


# --- the rows on tiny synthetic sequences, shipped self-model, tiny budgets ---------------------------------------


@pytest.fixture(scope="module")
def seq(hand):
    if not DEFAULT_MODEL.is_file():
        pytest.skip(f"shipped self-model missing: {DEFAULT_MODEL}")
    torch.set_num_threads(1)
    model, _ = load_selfmodel(DEFAULT_MODEL, hand, device="cpu")
    with SequenceImitator(model, TINY, loss_cfg=LossConfig(use_clip=False, crop_size=model.cfg.resolution)) as s:
        yield s


@pytest.fixture(scope="module")
def sequences(seq, hand):
    """Two synthetic sequences of rendered hand shadows: a pose moving in 3 steps (each frame its own keyframe at
    τ = 1) and 2 frames of one still pose (one keyframe: no transition)."""
    rng = np.random.default_rng(7)
    with CollisionWorld(hand) as world:
        q = sample_poses(hand, 1, rng)[0][0]
        while world.in_collision(q)[0]:
            q = sample_poses(hand, 1, rng)[0][0]
        step = np.zeros(21)
        step[[1, 2, 5, 6, 9, 10]] = 0.25
        poses = np.clip(q + np.arange(3)[:, None] * step, hand.lower, hand.upper)
    moving = sequence_from_masks(seq.renderer.render(poses), keyframe_cfg=KeyframeConfig(tau=1.0), name="moving")
    still = sequence_from_masks(seq.renderer.render(np.stack([q, q])), name="still")
    assert (len(moving.representatives), len(still.representatives)) == (3, 1)
    return [moving, still]


@pytest.fixture(scope="module")
def table(seq, sequences):
    return VideoEvaluator(seq, TINY).run(sequences)


@pytest.mark.slow
def test_six_rows_one_measure_and_counts_that_add_up(table, tmp_path):
    assert not table.cancelled and [r["row"] for r in table.rows] == [r.name for r in ROWS]
    assert len(table.records) == 14 and len(table.keyframes) == 7 * 4
    for r in table.rows:
        recs = [x for x in table.records if x["row"] == r["row"]]
        assert r["transitions"] == 2 + 0 == sum(x["transitions"] for x in recs)  # K − 1 per sequence, summed
        assert r["success"] == sum(x["success"] for x in recs) == sum(sum(x["ok"]) for x in recs)
        assert r["success_pct"] == pytest.approx(100 * r["success"] / 2)
        assert r["clip"] is None and r["exp_clip"] is None  # CLIP off: not computed, never 0
        assert r["exp_iou"] is not None and r["expr"] is not None  # Base rows too are scored with L_expr
        kfs = [k for k in table.keyframes if k["row"] == r["row"]]
        for k in kfs:
            assert k["total"] == pytest.approx(k["base"] + k["expr"])  # Total = L_base + L_expr
            assert (k["keyframe"] == 0) == math.isnan(k["temporal"])  # L_temp measured from the 2nd keyframe
        assert r["total"] == pytest.approx(np.mean([k["total"] for k in kfs]))
    paths = write_table(table, tmp_path)
    md = (tmp_path / "table2.md").read_text()
    for header in [*LOSS_COLUMNS, *EXTRA_COLUMNS]:
        assert f" {header} |" in md.splitlines()[0]
    assert md.count("\n| ") == 7 and "n/a" in md and "L_base + L_expr" in md and "CLIP off" in md
    rows = list(csv.DictReader(open(paths["csv"])))
    assert [r["row"] for r in rows] == [r.name for r in ROWS] and rows[0]["clip"] == "" and rows[0]["exp_iou"]
    assert len(list(csv.DictReader(open(paths["per_sequence"])))) == 14
    studio = next(r for r in table.rows if r["row"] == STUDIO_ROW.name)
    assert studio["late"] == 0  # kept to the clock: every transition within the servos' reach
    assert all(r["late"] is not None for r in table.rows) and "Success, L_total" in md
    settings = json.loads((tmp_path / "settings.json").read_text())
    assert settings["losses"]["use_clip"] is False and settings["sequence"]["first"]["batch"] == 8
    assert [s["keyframes"] for s in settings["sequences"]] == [3, 1]


@pytest.mark.slow
def test_sequential_temporal_row_moves_less(table):
    step = {r["row"]: r["mean_step"] for r in table.rows}
    assert step["Sequential +Exp+Temp"] < step["Independent +Exp"], step


@pytest.mark.slow
def test_cancel_keeps_the_finished_runs(seq, sequences):
    cancel = threading.Event()
    stages = []

    def progress(p):
        stages.append((p.stage, p.item))
        if p.item == "moving · Independent +Exp":
            cancel.set()

    result = VideoEvaluator(seq, TINY).run(sequences, progress, cancel=cancel)
    assert result.cancelled and [r["row"] for r in result.records] == ["Independent Base"]
    assert [r["row"] for r in result.rows] == ["Independent Base"] and "Cancelled: 1 of 14" in result.notes[-1]
    assert stages[0] == ("evaluate-video", "") and ("keyframe 1/3: search", "moving · Independent Base") in stages
    assert ("evaluate-video", "moving · Independent Base") in stages  # the run done, then the next one starts


# --- the verb end to end ------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_evaluate_video_cli_on_a_davis_sequence(shared_targets, tmp_path, capsys):
    if not DEFAULT_MODEL.is_file():
        pytest.skip(f"shipped self-model missing: {DEFAULT_MODEL}")
    out = tmp_path / "t2"
    threads = torch.get_num_threads()
    args = ["evaluate-video", str(shared_targets / "davis" / "blackswan"), "--out", str(out), "--no-clip", "--quiet"]
    assert main(args + TINY_FLAGS) == 0
    assert torch.get_num_threads() == threads
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert [r["row"] for r in summary["rows"]] == [r.name for r in ROWS] and summary["sequences"] == ["blackswan"]
    assert summary["clip"] is None and summary["cancelled"] is False and summary["preset"] == "studio"
    n = summary["rows"][0]["transitions"]
    assert n == summary["rows"][0]["keyframes"] - 1 >= 1 and all(r["transitions"] == n for r in summary["rows"])
    for name in ("table2.md", "table2.csv", "per_sequence.csv", "per_keyframe.csv", "settings.json"):
        assert (out / name).is_file(), name
    settings = json.loads((out / "settings.json").read_text())
    assert settings["sequence"]["first"]["batch"] == 8 and settings["video"]["hz"] == 4.0
    assert settings["sequences"][0]["frames"] == len(settings["sequences"][0]["assignment"])

    # spread over two worker processes (each with its own model): the same rows, seconds aside
    spread = tmp_path / "t2-spread"
    assert main(["evaluate-video", str(shared_targets / "davis" / "blackswan"), "--out", str(spread), "--no-clip",
                 "--quiet", "--workers", "2", *TINY_FLAGS]) == 0  # fmt: skip
    again = json.loads(capsys.readouterr().out.strip().splitlines()[-1])

    def timeless(rows: list[dict]) -> list[dict]:
        return [{k: v for k, v in r.items() if "seconds" not in k} for r in rows]

    assert timeless(again["rows"]) == timeless(summary["rows"]) and again["cancelled"] is False
    assert json.loads((spread / "settings.json").read_text())["workers"] == "2 local processes"

    assert main(["evaluate-video", str(tmp_path / "nowhere"), "--out", str(out), "--no-clip"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "not found" in err and "nowhere" in err
