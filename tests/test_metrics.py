"""Baselines and Table 1: every row and column, NaN handling, files written, valid poses, clear CLI errors."""

from __future__ import annotations

import csv
import json
import math

import cv2
import numpy as np
import pytest
import torch

from studio.cli.main import main
from studio.errors import TargetError
from studio.evaluate.baselines import InverseBaseline, NearestNeighbour, RandomImage, TrainingSet
from studio.evaluate.config import EvalConfig, NNConfig
from studio.evaluate.table1 import EXTRA_COLUMNS, LOSS_COLUMNS, METHODS, Evaluator, summarise, to_markdown, write_table
from studio.imitate.clip_loss import tiny_clip
from studio.imitate.config import RefineConfig, SearchConfig
from studio.imitate.still import Imitator
from studio.learn.checkpoint import save_model
from studio.learn.config import CollectConfig
from studio.learn.dataset import collect
from studio.learn.inverse import InverseCNN, InverseConfig
from studio.learn.selfmodel import SelfModel, SelfModelConfig
from studio.targets.holes import find_holes
from studio.targets.image_sets import gather_targets

RES = 32
TINY_MODEL = SelfModelConfig(resolution=RES, hidden=64, channels=16, min_channels=8, res_blocks=1)
TINY_INVERSE = InverseConfig(input_size=32, channels=(8, 16), hidden=32)
SEARCH = SearchConfig(batch=4, iterations=4)
REFINE = RefineConfig(restarts=2, steps=8)


def ring(res: int = RES) -> np.ndarray:
    """A synthetic target with one hole (an "o")."""
    img = np.zeros((res, res), np.uint8)
    cv2.circle(img, (res // 2, res // 2), res // 3, 1, -1)
    cv2.circle(img, (res // 2, res // 2), res // 8, 0, -1)
    return img


@pytest.fixture(scope="module")
def setup(tmp_path_factory, hand):
    """A tiny self-model, inverse CNN and shard set on disk, and an imitator around the model."""
    root = tmp_path_factory.mktemp("metrics")
    torch.manual_seed(0)
    model = SelfModel(TINY_MODEL, hand).eval()
    save_model(root / "model.pt", model, {"resolution": RES})
    save_model(root / "inverse.pt", InverseCNN(TINY_INVERSE, hand), {"resolution": RES})
    collect(root / "shards", CollectConfig(n=240, shard_size=120, resolution=RES), hand)
    data = TrainingSet.load(root / "shards", hand)
    with Imitator(model=model, search=SEARCH, refine=REFINE) as imitator:
        yield {"root": root, "imitator": imitator, "data": data, "hand": hand}


@pytest.fixture(scope="module")
def table(setup):
    """Table 1 on two training images and one ring with a hole."""
    imitator, data = setup["imitator"], setup["data"]
    plain = [m for m in data.shadows(slice(0, 40)) if not find_holes(m).any()][:2]  # training images, no holes
    targets = [("pose0", plain[0]), ("pose1", plain[1]), ("ring", ring())]
    with Evaluator(imitator, InverseCNN(TINY_INVERSE, setup["hand"]), data) as evaluator:
        return evaluator.run(targets)


def test_training_set_is_the_train_split(setup):
    assert len(setup["data"]) == 2 * 84  # 0.7 of each 120-pair shard
    assert setup["data"].shadows(slice(0, 3)).shape == (3, RES, RES)


@pytest.mark.slow
def test_table_has_every_row_and_column(table, tmp_path):
    assert [r["method"] for r in table.rows] == list(METHODS)
    for row in table.rows:
        assert set(LOSS_COLUMNS.values()) | set(EXTRA_COLUMNS.values()) <= set(row)
        assert row["targets"] == 3
        assert row["total"] >= row["base"] - 1e-9  # Total = Base (+ the expressive term on the ring)
        # every method's Base is positive, except Nearest Neighbour's could be 0 (two targets are training images)
        assert row["base"] > 0 or row["method"] == "Nearest Neighbour"
        assert row["clip"] is None and row["exp_clip"] is None  # no CLIP model: not computed
    json.dumps(table.rows, allow_nan=False)  # JSON-able (NaN → None)
    paths = write_table(table, tmp_path / "out")
    md = open(paths["markdown"]).read()
    for name in [*METHODS, *LOSS_COLUMNS, *EXTRA_COLUMNS]:
        assert name in md
    assert "n/a" in md and "holes" in md and "CLIP off" in md
    with open(paths["csv"]) as f:
        rows = list(csv.DictReader(f))
    assert [r["method"] for r in rows] == list(METHODS) and rows[0]["clip"] == ""
    with open(paths["per_target"]) as f:
        assert len(list(csv.DictReader(f))) == 3 * len(METHODS)


@pytest.mark.slow
def test_expressive_terms_only_over_targets_with_holes(table):
    ring_recs = [r for r in table.records if r["target"] == "ring"]
    plain = [r for r in table.records if r["target"] != "ring"]
    assert all(not math.isnan(r["exp_iou"]) for r in ring_recs)
    assert all(math.isnan(r["exp_iou"]) for r in plain)
    for row in table.rows:
        ours = next(r for r in ring_recs if r["method"] == row["method"])
        assert row["expressive_targets"] == 1 and row["exp_iou"] == pytest.approx(ours["exp_iou"])
        recs = [r for r in table.records if r["method"] == row["method"]]
        assert row["total"] == pytest.approx(np.mean([r["total"] for r in recs]))
    no_holes = summarise(plain)
    assert all(r["exp_iou"] is None and r["expressive_targets"] == 0 for r in no_holes)
    assert "| n/a | n/a |" in to_markdown(no_holes)


@pytest.mark.slow  # builds the table (11 s), as the other slow tests here do
def test_nearest_neighbour_finds_a_training_image(table, setup):
    nn = {r["target"]: r for r in table.records if r["method"] == "Nearest Neighbour"}
    assert nn["pose0"]["total"] == pytest.approx(0, abs=1e-6) and nn["pose1"]["base"] == pytest.approx(0, abs=1e-6)


def test_nearest_neighbour_matches_exhaustive_search(setup):
    imitator, data = setup["imitator"], setup["data"]
    target = imitator.renderer.render_one(setup["hand"].rest_pose())
    loss_fn = imitator.loss_fn(target)
    nn = NearestNeighbour(data, imitator.loss_cfg, NNConfig(rank_size=RES, shortlist=8, batch=50, chunk=64))
    out = nn.query(target, loss_fn)
    _, comps = loss_fn(torch.from_numpy(data.shadows(slice(None))).float())
    assert comps["base"][out.index].item() == pytest.approx(comps["base"].min().item(), abs=1e-6)


def test_baselines_return_valid_poses(setup):
    hand, data, imitator = setup["hand"], setup["data"], setup["imitator"]
    target = ring()
    nn = NearestNeighbour(data, imitator.loss_cfg)
    with InverseBaseline(InverseCNN(TINY_INVERSE, hand), imitator.renderer) as inverse:
        outs = [RandomImage(data, seed=1).query(), inverse.query(target), nn.query(target, imitator.loss_fn(target))]
    world = imitator.refiner.world
    for out in outs:
        assert out.theta.shape == (21,)
        assert np.all(out.theta >= hand.lower - 1e-6) and np.all(out.theta <= hand.upper + 1e-6)
        assert out.shadow.shape == (RES, RES) and set(np.unique(out.shadow)) <= {0, 1}
        # the shadow and the collision flag belong to the pose (training images: as collected in the shards)
        assert np.array_equal(out.shadow, imitator.renderer.render_one(out.theta))
        assert out.collides == bool(world.in_collision(out.theta)[0])
        assert out.seconds >= 0
    assert outs[0].index >= 0 and outs[2].index >= 0 and outs[1].index == -1


def test_baselines_and_evaluator_close_what_they_open(setup):
    import pybullet as p

    from studio.errors import ClosedError

    hand, imitator = setup["hand"], setup["imitator"]
    with InverseBaseline(InverseCNN(TINY_INVERSE, hand), imitator.renderer) as inverse:
        client = inverse.world.client
        assert p.isConnected(client)
    assert not p.isConnected(client)
    inverse.close()  # closing twice is fine
    with pytest.raises(ClosedError, match="InverseBaseline was closed"):
        inverse.query(ring())
    with Evaluator(imitator, InverseCNN(TINY_INVERSE, hand), setup["data"]) as evaluator:
        assert evaluator.inverse.world is imitator.refiner.world  # shared, not its own
    evaluator.close()
    assert p.isConnected(imitator.refiner.world.client)  # the imitator is the caller's: still open
    with pytest.raises(ClosedError, match="Evaluator was closed"):
        evaluator.run([("ring", ring())])


def test_recorded_collisions_match_the_poses(table, setup):
    world = setup["imitator"].refiner.world
    for rec in table.records:
        assert rec["collides"] == bool(world.in_collision(np.array(rec["theta"]))[0]), rec["method"]


def test_refinement_does_not_add_collisions(table):
    rows = {r["method"]: r for r in table.rows}
    assert rows["Ours"]["collide_pct"] <= rows["Ours w/o refinement"]["collide_pct"]
    assert rows["Ours"]["seconds"] >= rows["Ours w/o refinement"]["seconds"]


@pytest.mark.slow
def test_clip_columns_filled_with_a_clip_model(setup):
    with (
        Imitator(model=setup["imitator"].model, clip=tiny_clip(), search=SEARCH, refine=REFINE) as imitator,
        Evaluator(imitator, InverseCNN(TINY_INVERSE, setup["hand"]), setup["data"]) as evaluator,
    ):
        result = evaluator.run([("ring", ring())])
    for row in result.rows:
        assert row["clip"] is not None and row["exp_clip"] is not None
    assert not any("CLIP off" in n for n in result.notes)


@pytest.mark.slow
def test_scoring_at_another_side_renders_every_pose_there(setup):
    """score_resolution: each method's pose is rendered and scored at that side against the target framed there."""
    from studio.imitate.losses import ImageLoss
    from studio.sim.shadow import Rig, ShadowRenderer

    imitator, hand = setup["imitator"], setup["hand"]
    cfg = EvalConfig(score_resolution=64, roll=0)  # the rolled rows: the table fixture
    with Evaluator(imitator, InverseCNN(TINY_INVERSE, hand), setup["data"], cfg) as evaluator:
        assert evaluator.score_resolution == 64
        with pytest.raises(ValueError, match="64²"):
            evaluator.evaluate_target("ring", ring())
        result = evaluator.run([("ring", ring(), ring(64))])
    assert result.settings["score_resolution"] == 64 and result.settings["losses"]["crop_size"] == 64
    assert any("rendered at 64²" in n for n in result.notes)
    loss_fn = ImageLoss(ring(64), imitator.loss_cfg.__class__(use_clip=False, crop_size=64), None, find_holes(ring(64)))
    for rec in result.records:  # Random / Nearest Neighbour too: their training pose rendered at 64², not the image
        renderer = ShadowRenderer(hand, Rig(resolution=64, roll=math.radians(rec["roll_deg"])))  # the rolled rows too
        _, comps = loss_fn(torch.from_numpy(renderer.render_one(np.array(rec["theta"])).astype(np.float32)[None]))
        assert rec["total"] == pytest.approx(float(comps["total"][0]), abs=1e-5)
    with pytest.raises(ValueError, match="score_resolution"):
        EvalConfig(score_resolution=4)


def test_gather_targets_per_folder(tmp_path):
    for folder, n in (("a", 3), ("b", 1)):
        (tmp_path / folder).mkdir()
        for i in range(n):
            cv2.imwrite(str(tmp_path / folder / f"{i}.png"), ring() * 255)
    assert [p.parent.name for p in gather_targets([tmp_path], per_folder=1)] == ["a", "b"]
    assert len(gather_targets([tmp_path])) == 4
    (tmp_path / "empty").mkdir()
    with pytest.raises(TargetError, match="no target images"):
        gather_targets([tmp_path / "empty"])
    with pytest.raises(TargetError, match="not found"):
        gather_targets([tmp_path / "nowhere"])


def test_gather_targets_per_class(tmp_path):
    """MPEG-7 names: one image of each class, the name before its last '-' (``rat-01`` beside ``camel-1``)."""
    for name in ("camel-1", "camel-10", "camel-2", "rat-01", "rat-02", "key"):
        cv2.imwrite(str(tmp_path / f"{name}.png"), ring() * 255)
    assert [p.stem for p in gather_targets([tmp_path], per_class=1)] == ["camel-1", "key", "rat-01"]
    two = ["camel-1", "camel-10", "key", "rat-01", "rat-02"]  # first by name: camel-10 sorts before camel-2
    assert [p.stem for p in gather_targets([tmp_path], per_class=2)] == two
    with pytest.raises(ValueError, match="per_class .* at least 1"):
        gather_targets([tmp_path], per_class=0)


def _evaluate_args(setup, out, *targets) -> list[str]:
    root = setup["root"]
    return ["evaluate", *map(str, targets), "--out", str(out), "--model", str(root / "model.pt"),
            "--inverse", str(root / "inverse.pt"), "--nn-data", str(root / "shards"), "--no-clip", "--quiet",
            "--search-batch", "2", "--search-iterations", "2", "--refine-steps", "3",
            "--refine-restarts", "2"]  # fmt: skip


@pytest.mark.slow
def test_evaluate_cli_writes_table_and_prints_json_last(setup, tmp_path, capsys):
    for letter in "ab":
        (tmp_path / "t" / letter).mkdir(parents=True)
        for i in range(2):
            cv2.imwrite(str(tmp_path / "t" / letter / f"{i}.png"), ring(64) * 255)
    threads = torch.get_num_threads()
    assert main(_evaluate_args(setup, tmp_path / "out", tmp_path / "t") + ["--per-folder", "1"]) == 0
    assert torch.get_num_threads() == threads  # --threads is restored afterwards
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert [r["method"] for r in summary["rows"]] == list(METHODS)
    assert summary["rows"][0]["targets"] == 2 and summary["clip"] is None
    settings = json.loads((tmp_path / "out" / "settings.json").read_text())
    assert settings["losses"]["use_clip"] is False and settings["refine"]["steps"] == 3
    assert settings["score_resolution"] == RES  # the model's side unless --score-resolution is given
    assert (tmp_path / "out" / "table1.md").is_file() and (tmp_path / "out" / "table1.csv").is_file()


@pytest.mark.slow
def test_evaluate_cli_on_two_worker_processes_gives_the_same_rows(setup, tmp_path, capsys):
    """`evaluate --workers 2`: every target on a spawned worker with its own models, the same rows (seconds aside)
    and the same settings as in one process."""
    (tmp_path / "t").mkdir()
    for i in range(3):
        cv2.imwrite(str(tmp_path / "t" / f"{i}.png"), np.roll(ring(64), 4 * i, axis=1) * 255)
    runs = {}
    for how in ([], ["--workers", "2"]):
        assert main(_evaluate_args(setup, tmp_path / f"out{len(how)}", tmp_path / "t") + ["--roll", "0", *how]) == 0
        runs[len(how)] = json.loads(capsys.readouterr().out.strip().splitlines()[-1])

    def rows(summary: dict) -> list[dict]:
        return [{k: v for k, v in r.items() if not k.startswith("seconds")} for r in summary["rows"]]

    assert rows(runs[2]) == rows(runs[0]) and runs[2]["rows"][0]["targets"] == 3 and not runs[2]["cancelled"]
    settings = json.loads((tmp_path / "out2" / "settings.json").read_text())
    assert settings["workers"] == "2 local processes" and settings["refine"]["steps"] == 3


def test_evaluate_cli_errors_are_one_line(setup, tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(_evaluate_args(setup, tmp_path / "out", tmp_path / "empty")) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no target images" in err and "empty" in err

    bad = tmp_path / "bad.png"
    bad.write_bytes(b"this is not an image")
    assert main(_evaluate_args(setup, tmp_path / "out", bad)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "bad.png" in err

    good = tmp_path / "good.png"
    cv2.imwrite(str(good), ring(64) * 255)
    args = _evaluate_args(setup, tmp_path / "out", good)
    args[args.index("--nn-data") + 1] = str(tmp_path / "no-shards")
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--nn-data" in err and "shadow-studio collect" in err
    assert main([*args, "--workers", "2"]) == 2  # the same line, before the index is built or a worker starts
    assert capsys.readouterr().err.strip() == err
