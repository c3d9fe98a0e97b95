"""The one progress protocol (studio.errors): every long engine call reports typed Progress events (a strict
ProgressFn fails on any other call shape), TqdmBars draws a bare Progress stream and job events alike (none with
--quiet), and Ctrl-C → cancel (the first sets the event, the second stops at once), driven by real signals."""

from __future__ import annotations

import io
import math
import os
import signal
import sys
import time

import numpy as np
import pytest

from studio.cli.progress import ctrl_c_cancels
from studio.errors import Progress, report, staged, stopped
from studio.jobs.bars import TqdmBars
from studio.jobs.events import JobEvent, JobState


def _ctrl_c() -> None:
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(0.05)  # the handler runs at the next bytecode boundary of the main thread


def test_first_ctrl_c_sets_cancel_second_interrupts_and_the_handler_is_restored():
    before = signal.getsignal(signal.SIGINT)
    with ctrl_c_cancels() as cancel:
        assert not cancel.is_set() and not stopped(cancel)
        _ctrl_c()
        assert cancel.is_set() and stopped(cancel)
        with pytest.raises(KeyboardInterrupt):
            _ctrl_c()
    assert signal.getsignal(signal.SIGINT) is before and not stopped(None)


def test_report_and_staged_build_progress_events():
    seen: list[Progress] = []
    report(seen.append, "search", 3, 10, 0.5)
    report(None, "search", 4, 10)  # no sink: nothing
    staged(seen.append, "keyframe 2/5: ")(Progress("refine", 1, 4, item="a"))
    staged(seen.append, "", item="seq · row")(Progress("search", 2, 4))
    assert seen == [Progress("search", 3, 10, 0.5), Progress("keyframe 2/5: refine", 1, 4, item="a"),
                    Progress("search", 2, 4, item="seq · row")]  # fmt: skip
    assert seen[0].fraction == 0.3 and math.isnan(Progress("x").fraction) and staged(None, "x") is None


def test_tqdm_bars_draw_a_bare_progress_stream_one_bar_per_stage():
    out = io.StringIO()
    with TqdmBars(file=out, mininterval=0) as bars:
        bars(Progress("search", 1, 4, 0.5))
        bars(Progress("search", 4, 4, 0.25))
        bars(Progress("refine", 2, 2, math.nan, "a.png"))  # the search is done: a refine bar replaces it
        assert [s for s, _ in bars._bars[0]] == ["refine"]
        bars(Progress("evaluate", 0, 3))
        bars(Progress("search", 2, 4, 0.125, "b.png"))  # unfinished "evaluate" above: a bar beneath it
        assert [s for s, _ in bars._bars[0]] == ["evaluate", "search"]
        bars(Progress("evaluate", 1, 3, item="b.png"))  # the outer stage again: the search bar beneath closes
        assert [s for s, _ in bars._bars[0]] == ["evaluate"]
    assert bars._bars == {}  # closed on the way out
    text = out.getvalue()
    assert "search: 100%" in text and "4/4" in text and "best 0.2500" in text
    assert "refine: 100%" in text and "2/2" in text and "a.png" in text and "best nan" not in text
    assert "evaluate:  33%" in text and "1/3" in text and "best 0.1250, b.png" in text
    assert "#0" not in text  # a bare stream is no job


def test_tqdm_bars_take_job_events_and_a_bare_stream_together():
    out = io.StringIO()

    def event(state, stage="", step=0, total=0, best=math.nan, item="", job=3):
        return JobEvent(job, "imitate-keyframe", state, stage, step, total, best, None, 0.0, 0, item=item)

    bars = TqdmBars(file=out, mininterval=0)
    bars(event(JobState.QUEUED))
    bars(event(JobState.RUNNING, "start"))  # no bar of its own
    bars(Progress("read", 1, 2))  # an engine call beside the job: job 0
    bars(event(JobState.RUNNING, "search", 5, 20, 0.75, "asl_v.jpeg"))
    assert sorted(bars._bars) == [0, 3]
    bars(event(JobState.DONE, "apply"))  # the final event closes the job's bar
    assert sorted(bars._bars) == [0]
    bars.close()
    text = out.getvalue()
    assert "#3 imitate-keyframe: search" in text and "5/20" in text and "best 0.7500, asl_v.jpeg" in text
    assert "read:  50%" in text and "start" not in text


def test_quiet_draws_nothing():
    out = io.StringIO()
    with TqdmBars(file=out, disable=True) as bars:
        bars(Progress("search", 1, 4, 0.5))
        bars(JobEvent(1, "plan", JobState.RUNNING, "path", 1, 3, math.nan, None, 0.0, 1))
    assert out.getvalue() == "" and bars._bars == {}


class Strict:
    """A ProgressFn that takes nothing but one Progress (an old-shape call fails here), with sane numbers."""

    def __init__(self):
        self.events: list[Progress] = []

    def __call__(self, *args, **kwargs) -> None:
        assert len(args) == 1 and not kwargs and isinstance(args[0], Progress), (args, kwargs)
        p = args[0]
        assert p.stage and 0 <= p.step and (p.total == 0 or p.step <= p.total), p
        self.events.append(p)

    def take(self) -> list[str]:
        stages, self.events = [p.stage for p in self.events], []
        return stages


def test_every_long_engine_call_reports_typed_progress(tmp_path, hand):
    """search, refine, sweep, the index, seeding, a still, a sequence, collect, train, Table 1, Table 2, plan and
    playback, each with a strict ProgressFn."""
    from studio.evaluate.baselines import TrainingSet
    from studio.evaluate.sequences import PreparedSequence
    from studio.evaluate.table1 import Evaluator
    from studio.evaluate.table2 import ROWS, VideoEvaluator
    from studio.imitate.candidates import refine_best
    from studio.imitate.config import ImitateConfig, LossConfig, RefineConfig, SearchConfig, SequenceConfig, SweepConfig
    from studio.imitate.retrieval import RetrievalConfig, RetrievalIndex
    from studio.imitate.search import gradient_search
    from studio.imitate.sequence import SequenceImitator
    from studio.imitate.still import Imitator
    from studio.imitate.sweep import block_sweep, joint_blocks
    from studio.learn.config import CollectConfig, TrainConfig
    from studio.learn.dataset import collect
    from studio.learn.inverse import InverseCNN, InverseConfig
    from studio.learn.selfmodel import SelfModel, SelfModelConfig
    from studio.learn.train import train
    from studio.motion.plan import Keyframes, plan_show
    from studio.sim.shadow import Rig, ShadowRenderer

    strict = Strict()
    collect(tmp_path / "shards", CollectConfig(n=60, shard_size=30, resolution=32), hand, progress=strict)
    assert strict.take() == ["collect"] * 2
    train(TrainConfig(out=str(tmp_path / "m.pt"), resolution=16, steps=2, batch_size=4, warmup=1, eval_every=1,
                      eval_size=8, threads=1), hand, progress=strict)  # fmt: skip
    assert strict.take() == ["train", "val", "train", "val", "test"]

    renderer = ShadowRenderer(hand, Rig(resolution=32))
    index = RetrievalIndex.build(renderer, RetrievalConfig(size=600, chunk=300, shortlist=24, seed=5), progress=strict)
    assert strict.events[-1] == Progress("index", 600, 600) and set(strict.take()) == {"index"}
    model = SelfModel(SelfModelConfig(resolution=32, hidden=32, channels=16, min_channels=8, res_blocks=1), hand)
    sweep = SweepConfig(starts=1, draws=16, wrist_draws=8, passes=1)
    refine = RefineConfig(method="cmaes", restarts=1, steps=2, popsize=4, log_every=1)
    loss_cfg = LossConfig(use_clip=False, crop_size=32)
    search = SearchConfig(batch=4, iterations=2, log_every=1)
    with Imitator(model, loss_cfg=loss_cfg, retrieval=index, search=search, refine=refine, sweep=sweep,
                  config=ImitateConfig(candidates=1)) as im:  # fmt: skip
        target = renderer.render_one(index.theta[7])
        loss_fn = im.loss_fn(target)
        gradient_search(model, loss_fn, search, progress=strict)
        assert strict.take() == ["search"] * 2
        im.refiner.refine(loss_fn, index.theta[7], refine, progress=strict)
        refine_best(im.refiner, loss_fn, index.theta[:2], np.zeros(2), 1, refine, progress=strict)
        assert strict.take() == ["refine"] * 4
        blocks = joint_blocks(hand)
        block_sweep(index.theta[7].astype(float), 1.0, blocks, hand.lower, hand.upper, lambda th: np.ones(len(th)),
                    lambda th: np.zeros(len(th), bool), sweep, np.random.default_rng(0), progress=strict)  # fmt: skip
        assert strict.take() == ["sweep"] * len(blocks)
        im.seed(loss_fn, target, progress=strict)
        assert (stages := strict.take())[0] == "retrieve" and set(stages[1:]) == {"sweep"}
        im.imitate(target, progress=strict)
        assert set(strict.take()) == {"retrieve", "sweep", "search", "refine"}

        seq_cfg = SequenceConfig(first=search, next=search, refine=refine, candidates=1, expressive=False,
                                 retrieve=True, sweep=sweep)  # fmt: skip
        masks = np.stack([target, renderer.render_one(index.theta[8])])
        SequenceImitator(cfg=seq_cfg, imitator=im).imitate(masks, progress=strict)
        assert {"keyframe 1/2: retrieve", "keyframe 1/2: search", "keyframe 2/2: refine"} <= set(strict.take())

        data = TrainingSet.load(tmp_path / "shards", hand)
        inverse = InverseCNN(InverseConfig(input_size=32, channels=(8, 16), hidden=32), hand)
        with Evaluator(im, inverse, data) as evaluator:
            evaluator.run([("a", target)], progress=strict)
        assert strict.events[0] == Progress("evaluate", 0, 1)
        assert strict.events[-1] == Progress("evaluate", 1, 1, item="a")  # the target done, by name
        assert all(p.item == "a" for p in strict.events[1:]) and "search" in strict.take()

        s = PreparedSequence("s", tmp_path, np.zeros(2), np.arange(2), np.arange(2), masks, masks, 0.0)
        VideoEvaluator(SequenceImitator(cfg=seq_cfg, imitator=im), seq_cfg, rows=ROWS[:1]).run([s], strict)
        assert strict.events[-1] == Progress("evaluate-video", 1, 1, item="s · Independent Base")
        assert "keyframe 2/2: search" in strict.take()

    q = hand.rest_pose().copy()
    q[hand.joint_names.index("index_pip")] = 0.6
    show = plan_show(hand, Keyframes.at([0.5], [q]), progress=strict).show
    assert strict.take() == ["keyframes"] * 2 + ["path"] * 3 + ["timing", "show"]
    if sys.platform != "win32":  # playback on the emulator (POSIX pseudo-terminals): a Progress per tick
        from hardware.dry_run import play_show

        played = play_show(show, progress=strict)
        last = strict.events[-1]
        assert played.ok and last.stage == "play" and last.step == last.total > 0 and set(strict.take()) == {"play"}
