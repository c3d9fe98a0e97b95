"""Spreading work (studio.learn.fanout): in this process, on spawned processes and on one real local Ray (two CPUs,
shared by the module) the same shards and the same Table 1; a failing item is named; a cancel keeps what finished.
Training on that Ray through Ray Train: `train --ray` stopped by Ctrl-C resumes to the one process's weights, and the
verb's refusals come before Ray starts (one Ray for the module: each start costs ~13 s of CPU on CI's two cores)."""

from __future__ import annotations

import json
import shutil
import threading
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from ctrl_c_support import ctrl_c_once_written  # this folder's helper

from studio.cli.main import main
from studio.evaluate.config import EvalConfig
from studio.evaluate.table1 import Evaluator
from studio.evaluate.table1_task import Table1Task, evaluate_spread
from studio.evaluate.worker_models import ModelRecipe
from studio.imitate.config import ImitateConfig, RefineConfig, SearchConfig, SweepConfig
from studio.imitate.index_cache import cached_index
from studio.imitate.retrieval import RetrievalConfig
from studio.imitate.still import Imitator
from studio.learn.checkpoint import read_checkpoint, save_model
from studio.learn.config import CollectConfig, TrainConfig
from studio.learn.dataset import ShardTask, collect
from studio.learn.fanout import FanoutConfig, FanoutError, fan_out
from studio.learn.inverse import InverseCNN, InverseConfig
from studio.learn.selfmodel import SelfModel, SelfModelConfig, load_selfmodel
from studio.learn.shards import list_shards
from studio.learn.train import train
from studio.sim.sampling import SamplerConfig

pytestmark = pytest.mark.slow

RES = 32
LOCAL, PROCESSES = FanoutConfig(), FanoutConfig(workers=2)
SMALL = CollectConfig(n=120, shard_size=30, resolution=RES)


@pytest.fixture(scope="module")
def ray_cluster():
    """One local Ray of two CPUs for the module (a fan-out uses a Ray it finds running and leaves it)."""
    import ray  # a dependency (pyproject): a missing install fails here, never skips

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield FanoutConfig(workers=2, ray="local")
    ray.shutdown()


def shard_bytes(folder) -> list[bytes]:
    return [p.read_bytes() for p in list_shards(folder)]


def test_collect_makes_the_same_shards_in_process_on_processes_and_on_ray(tmp_path, hand, ray_cluster):
    made = {}
    for name, how in {"local": LOCAL, "processes": PROCESSES, "ray": ray_cluster}.items():
        summary = collect(tmp_path / name, SMALL, hand, fanout=how)
        assert summary["written"] == 4 and summary["samples"] == 120 and summary["workers"] == how.where
        made[name] = shard_bytes(tmp_path / name)
    assert len(made["local"]) == 4 and made["processes"] == made["local"] and made["ray"] == made["local"]
    again = collect(tmp_path / "ray", SMALL, hand, fanout=ray_cluster)  # resumable: nothing is made twice
    assert again["written"] == 0 and again["skipped"] == 4 and shard_bytes(tmp_path / "ray") == made["local"]


@pytest.mark.parametrize("where", ["local", "processes", "ray"])
def test_follow_ups_run_after_the_item_that_brings_them(tmp_path, where, request):
    """Two chains of shards (0 → 1, 2 → 3): each follow-up goes out only once the item before it has finished and
    run; the same shards are written whichever way the work ran, and progress counts towards the total given."""
    how = {"local": LOCAL, "processes": PROCESSES}.get(where) or request.getfixturevalue("ray_cluster")
    items, written, seen = [0, 2], [], []  # items: the fan-out's, follow-ups appended after the items given

    def then(i: int, result: tuple[int, bool]) -> list[int]:
        k = items[i]
        assert result == (30, True) and (tmp_path / f"shard_{k:05d}.npz").exists()  # it ran before its follow-up
        written.append(k)
        more = [k + 1] if k % 2 == 0 else []
        items.extend(more)
        return more

    done = fan_out(ShardTask(tmp_path, SMALL, SamplerConfig()), list(items), how, progress=seen.append,
                   stage="shards", names=lambda k: f"shard {k}", on_result=then, total=4)  # fmt: skip
    assert set(done) == {0, 1, 2, 3} and sorted(written) == [0, 1, 2, 3] and sorted(items) == [0, 1, 2, 3]
    assert written.index(1) > written.index(0) and written.index(3) > written.index(2)
    assert [p.total for p in seen] == [4] * 5 and [p.step for p in seen] == list(range(5))
    assert {p.item for p in seen[1:]} == {"shard 0", "shard 1", "shard 2", "shard 3"}
    assert len(list_shards(tmp_path)) == 4


@pytest.mark.parametrize("where", ["processes", "ray"])
def test_a_failing_item_is_named_and_stops_the_run(tmp_path, where, request, capfd):
    how = PROCESSES if where == "processes" else request.getfixturevalue("ray_cluster")
    (tmp_path / "shard_00002.npz").mkdir()  # shard 2 cannot be written: a folder stands where the file goes
    task = ShardTask(tmp_path, SMALL, SamplerConfig())
    with pytest.raises(FanoutError, match=r"item 2 \(shard 2\) failed: .*Error"):  # by its name, not its repr
        fan_out(task, range(SMALL.num_shards), how, names=lambda k: f"shard {k}")
    # workers that cannot set up (a rig file that is not there): the error once, and no worker's traceback
    broken = ShardTask(tmp_path / "b", replace(SMALL, rig_file=str(tmp_path / "no_rig.yaml")), SamplerConfig())
    with pytest.raises(FanoutError, match=r"^a worker could not start: \w+: .*no_rig\.yaml"):
        fan_out(broken, range(SMALL.num_shards), how)
    assert "Traceback" not in capfd.readouterr().err


def test_a_cluster_address_where_nothing_answers_is_refused_at_once():
    from studio.learn.ray_cluster import RayUnavailable, _answers

    with pytest.raises(RayUnavailable, match=r"127\.0\.0\.1:1: nothing answers there .*ray start --head"):
        _answers("127.0.0.1:1")  # (Ray itself would retry for minutes)
    assert _answers("auto") is None  # Ray finds a running cluster itself


def test_a_cancel_keeps_the_finished_items(tmp_path, hand):
    cancel, seen = threading.Event(), []

    def progress(p):
        seen.append(p.step)
        if p.step >= 1:
            cancel.set()

    cfg = CollectConfig(n=600, shard_size=30, resolution=RES)
    summary = collect(tmp_path, cfg, hand, progress=progress, cancel=cancel, fanout=PROCESSES)
    kept = list_shards(tmp_path)
    assert 1 <= summary["written"] < cfg.num_shards and len(kept) >= summary["written"]
    assert summary["samples"] == 30 * summary["written"]
    again = collect(tmp_path, cfg, hand)  # the same command again continues: nothing lost, nothing redone twice
    assert again["skipped"] >= summary["written"] and again["samples"] == 600


@pytest.fixture(scope="module")
def table_task(tmp_path_factory, hand):
    """A tiny self-model, inverse CNN, training shards and retrieval index on disk, and the task that reads them."""
    root = tmp_path_factory.mktemp("spread")
    torch.manual_seed(0)
    tiny = SelfModelConfig(resolution=RES, hidden=64, channels=16, min_channels=8, res_blocks=1)
    save_model(root / "model.pt", SelfModel(tiny, hand).eval(), {"resolution": RES})
    save_model(root / "inverse.pt", InverseCNN(InverseConfig(input_size=32, channels=(8, 16), hidden=32), hand),
               {"resolution": RES})  # fmt: skip
    collect(root / "shards", CollectConfig(n=240, shard_size=120, resolution=RES), hand)
    retrieval = RetrievalConfig(size=3000, chunk=1500, shortlist=16)
    model, _ = load_selfmodel(root / "model.pt", device="cpu")
    with Imitator(model, retrieval=retrieval) as im:
        cached_index(im.renderer, retrieval)  # built once here; every worker loads it from the cache
    budget = SearchConfig(batch=4, iterations=4), RefineConfig(restarts=2, steps=8), ImitateConfig()
    models = ModelRecipe(str(root / "model.pt"), device="cpu", use_clip=False)
    return Table1Task(models, str(root / "inverse.pt"), str(root / "shards"), EvalConfig(seed=3, roll=0), *budget,
                      SweepConfig(starts=0), retrieval=retrieval)  # fmt: skip


def targets(n: int) -> list[tuple[str, np.ndarray]]:
    out = []
    for i in range(n):
        img = np.zeros((RES, RES), np.uint8)
        img[6 + i : 26 - i, 8 : 12 + 3 * i] = 1
        out.append((f"bar{i}", img))
    return out


def comparable(records: list[dict]) -> list[dict]:
    """The records without their timing, NaN (a term not computed) as None so that equal means equal."""
    nan = lambda v: None if isinstance(v, float) and np.isnan(v) else v  # noqa: E731
    return [{k: nan(v) for k, v in r.items() if k not in ("seconds", "seconds_p50", "seconds_max")} for r in records]


def test_table1_spread_over_workers_equals_one_process(table_task, ray_cluster):
    """Table 1 in one process (Evaluator.run, the reference), spread over two processes and over two Ray actors:
    the same records and rows (seconds aside), in the targets' order."""
    ts = targets(3)
    table_task.setup()
    try:
        reference = table_task._held[1].run(ts)
    finally:
        table_task.close()
    for how in (PROCESSES, ray_cluster):
        got = evaluate_spread(table_task, ts, how)
        assert [r["target"] for r in got.records] == [r["target"] for r in reference.records]
        assert comparable(got.records) == comparable(reference.records), how.where
        assert comparable(got.rows) == comparable(reference.rows)
        assert got.settings["workers"] == how.where and got.notes[0].startswith("3 targets at 32²")


def test_random_draws_by_target_index_not_by_order(table_task):
    """Random's draw for target i comes from (seed, i): the same whichever targets ran before it."""
    task = replace(table_task)
    task.setup()
    try:
        evaluator: Evaluator = task._held[1]
        a = evaluator.random.query(5).theta
        evaluator.random.query(0)
        assert np.array_equal(evaluator.random.query(5).theta, a)
        assert not np.array_equal(evaluator.random.query(6).theta, a)
    finally:
        task.close()


def test_the_retrieval_index_built_on_processes_and_on_ray_is_the_one_built_here(hand, ray_cluster):
    """The chunks are drawn here in the same order wherever they are checked, rendered and packed."""
    from studio.imitate.retrieval import RetrievalIndex
    from studio.sim.shadow import Rig, ShadowRenderer

    renderer = ShadowRenderer(hand, Rig(resolution=RES))
    cfg = RetrievalConfig(size=1500, chunk=400, shortlist=8, seed=11)
    here = RetrievalIndex.build(renderer, cfg)
    assert len(here.theta) == cfg.size
    for how in (PROCESSES, ray_cluster):
        spread = RetrievalIndex.build(renderer, cfg, fanout=how)
        assert np.array_equal(spread.theta, here.theta) and np.array_equal(spread.bits, here.bits), how.where
        assert spread.key == here.key
    cancel = threading.Event()
    cancel.set()
    assert RetrievalIndex.build(renderer, cfg, fanout=PROCESSES, cancel=cancel) is None


# --- project run over many sources -------------------------------------------------------------------------------
TINY_RUN = ["--search-batch", "8", "--search-iterations", "20", "--next-batch", "8", "--next-iterations", "10",
            "--refine-steps", "30", "--refine-restarts", "2", "--candidates", "1", "--sweep-draws", "96",
            "--sweep-passes", "1", "--joint-generations", "10", "--allow-late", "--threads", "1",
            "--quiet"]  # fmt: skip


def test_a_project_runs_its_sources_side_by_side_with_the_poses_of_one_process(tmp_path, hand, ray_cluster, capsys):
    """``project run --workers 2 --ray``: one source per worker (a chain in order, each keyframe continuing from the
    one before it and kept within reach on the show's clock), the same poses as the run in this process, the
    results saved and the show planned."""
    from studio.assets import asset

    from studio.cli.main import main
    from studio.project.project import Project
    from studio.targets.keyframes import KeyframeConfig
    from studio.targets.video import DEFAULT_VIDEO

    base = Project.create(tmp_path / "base.shadow", sources=[asset("targets/asl_o.jpeg"), DEFAULT_VIDEO],
                          clustering=KeyframeConfig(tau=0.35))  # fmt: skip
    base.set_roll(0.0)
    assert sum(base.frames[kf.representative].source == 1 for kf in base.keyframes) >= 2  # the video: a chain
    poses, threads = {}, torch.get_num_threads()
    try:
        for name, how in {"one": [], "ray": ["--workers", "2", "--ray"]}.items():  # (processes: the same fan_out)
            folder = tmp_path / f"{name}.shadow"
            shutil.copytree(base.path, folder)
            assert main(["project", "run", str(folder), *TINY_RUN, *how]) == 0
            summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
            project = Project.open(folder)
            assert summary["show"] == "planned" and project.pending_keyframes() == [] and project.show is not None
            poses[name] = np.stack([project.results[kf.id].theta(hand.joint_names) for kf in project.keyframes])
    finally:
        torch.set_num_threads(threads)
    assert np.array_equal(poses["ray"], poses["one"])


def test_a_cancelled_spread_run_keeps_every_keyframe_finished(tmp_path, hand, ray_cluster):
    """A spread run cancelled once its first keyframe came back: that keyframe is saved (the rest of its source's
    chain is not lost with it) awaiting its refinement together with them, the others stay pending, and the report
    says so."""
    from studio.cli.main import build_parser
    from studio.cli.run_flags import run_config_from_args
    from studio.evaluate.worker_models import ModelRecipe
    from studio.imitate.still import DEFAULT_MODEL
    from studio.project.project import Project
    from studio.project.run import run_project
    from studio.targets.keyframes import KeyframeConfig
    from studio.targets.video import DEFAULT_VIDEO

    project = Project.create(tmp_path / "cut.shadow", sources=[DEFAULT_VIDEO], clustering=KeyframeConfig(tau=0.35))
    project.set_roll(0.0)
    n = len(project.keyframes)
    assert n >= 2  # one chain: without keyframe saves it would lose everything
    args = build_parser().parse_args(["project", "run", str(project.path), *TINY_RUN])
    cfg = replace(run_config_from_args(args), fanout=ray_cluster)
    cancel, seen = threading.Event(), []

    def progress(p):
        if p.stage == "keyframes":
            seen.append((p.step, p.total, p.item))
            if p.step >= 1:
                cancel.set()

    threads = torch.get_num_threads()
    try:
        report = run_project(project, cfg, cancel=cancel, progress=progress,
                             models=ModelRecipe(str(DEFAULT_MODEL), "cpu", use_clip=False))  # fmt: skip
    finally:
        torch.set_num_threads(threads)
    assert report.cancelled and report.optimised == [project.keyframes[0].id], report.message
    assert "1 keyframe finished and saved" in report.message
    assert seen[0][:2] == (0, n) and seen[1] == (1, n, DEFAULT_VIDEO.name)
    again = Project.open(project.path)
    assert list(again.results) == [project.keyframes[0].id]
    assert again.pending_keyframes() == [kf.id for kf in project.keyframes[1:]]
    assert again.results[project.keyframes[0].id].awaits == "together"  # the resumed run refines it with the others


# ---------------------------------------------------------------- training on Ray (Ray Train)
def tiny(out, steps: int = 8) -> TrainConfig:
    """A 16² self-model rendered on the fly: global batch 8, validation every 4 steps."""
    return TrainConfig(out=str(out), model="cpu", resolution=16, steps=steps, batch_size=8, warmup=2, eval_every=4,
                       eval_size=16, threads=1, device="cpu")  # fmt: skip


def weights(path) -> dict[str, torch.Tensor]:
    return read_checkpoint(path, "selfmodel").state_dict


def test_train_on_ray_stopped_by_ctrl_c_resumes_to_the_one_process_weights(
    tmp_path, hand, ray_cluster, capsys, monkeypatch
):
    """`train --ray` on two Ray Train workers at the same global batch as one process, stopped by Ctrl-C after its
    first checkpoint: it reports the steps it made, exits 130 and leaves a checkpoint that `train --resume` (one
    process) continues to the end, to the one process's weights and metrics (so every Ray step was the one process's
    step). Its ``--out`` is relative, as typed in a shell: the checkpoint lands where the verb was started (Ray Train
    starts its workers in folders of their own)."""
    whole = tiny(tmp_path / "whole.pt", steps=40)
    reference = train(whole, hand)
    monkeypatch.chdir(tmp_path)
    parts = Path("parts.pt")
    with ctrl_c_once_written(parts):  # the first checkpoint: step 4 of 40
        code = main([*verb(parts, 40, quiet=False), "--workers", "2", "--ray"])
    captured = capsys.readouterr()
    cut = json.loads(captured.out.strip().splitlines()[-1])
    done = read_checkpoint(parts, "selfmodel").extra["step"]
    assert code == 130 and cut["cancelled"] is True and 4 <= done < 40 and cut["steps"] == done
    assert f"{done}/40" in captured.err  # worker 0's progress reached the verb's bar, to the step it stopped at
    assert main([*verb(parts, 40), "--resume"]) == 0
    resumed = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "cancelled" not in resumed and resumed["steps"] == 40
    assert resumed["train_mae"] == pytest.approx(reference["train_mae"], rel=1e-3)
    assert resumed["test_mae"] == pytest.approx(reference["test_mae"], rel=1e-3)
    for k, w in weights(whole.out).items():
        torch.testing.assert_close(weights(parts)[k], w, rtol=1e-3, atol=1e-4)


def verb(out, steps: int, quiet: bool = True) -> list[str]:
    """`shadow-studio train` with the flags of :func:`tiny` (``quiet``: no progress bar)."""
    return ["train", "--out", str(out), "--resolution", "16", "--steps", str(steps), "--batch-size", "8",
            "--warmup", "2", "--eval-every", "4", "--eval-size", "16", "--threads", "1", "--device", "cpu",
            *(["--quiet"] if quiet else [])]  # fmt: skip


def test_the_train_verbs_refusals_come_before_ray_starts(tmp_path, capsys):
    out = tmp_path / "m.pt"
    assert main([*verb(out, 4), "--workers", "2"]) == 2  # workers without Ray: one line saying to add --ray
    assert "add --ray" in capsys.readouterr().err
    assert main([*verb(out, 4), "--workers", "3", "--ray"]) == 2  # 8 does not split over 3 workers
    err = capsys.readouterr().err
    assert "does not split evenly over 3 workers" in err and "Traceback" not in err
    out.write_bytes(b"")
    assert main([*verb(out, 4), "--workers", "2", "--ray"]) == 2  # exists: --resume or --force
    assert "--resume" in capsys.readouterr().err
