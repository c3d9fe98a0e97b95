"""studio.cli.sequence_flags: one set of preset + budget flags for imitate-video and evaluate-video, each flag
overriding one field of the preset only when given."""

from __future__ import annotations

from dataclasses import replace

import pytest

from studio.cli.main import build_parser
from studio.cli.sequence_flags import sequence_config_from_args
from studio.imitate.config import CPU_SEQUENCE, PAPER_SEQUENCE

VERBS = (["imitate-video", "clip.gif", "--out", "o"], ["evaluate-video", "clip.gif", "--out", "o"])
BUDGET = ["--preset", "paper", "--first-batch", "8", "--next-iters", "7", "--refine-restarts", "3", "--candidates", "2"]


def config(*argv: str):
    return sequence_config_from_args(build_parser().parse_args(list(argv)))


@pytest.mark.parametrize("verb", VERBS, ids=lambda v: v[0])
def test_no_flags_is_the_cpu_preset_and_paper_keeps_every_size_not_given(verb):
    assert config(*verb) == CPU_SEQUENCE
    assert config(*verb, "--preset", "paper") == PAPER_SEQUENCE
    cfg = config(*verb, *BUDGET)
    assert cfg.first == replace(PAPER_SEQUENCE.first, batch=8)
    assert cfg.next == replace(PAPER_SEQUENCE.next, iterations=7)
    assert cfg.refine == replace(PAPER_SEQUENCE.refine, restarts=3)
    assert cfg.candidates == 2 and cfg.mode == PAPER_SEQUENCE.mode
    swept = config(*verb, "--sweep-draws", "64", "--sweep-passes", "1")
    assert swept == replace(CPU_SEQUENCE, sweep=replace(CPU_SEQUENCE.sweep, draws=64, passes=1))


def test_both_verbs_read_the_same_flags_the_same_way():
    (video, table) = VERBS
    assert config(*video, *BUDGET, "--seed", "5") == config(*table, *BUDGET, "--seed", "5")
    cfg = config(*table, "--seed", "5")
    assert (cfg.first.seed, cfg.next.seed, cfg.refine.seed, cfg.sweep.seed) == (5, 5, 5, 5)


def test_imitate_video_also_sets_mode_terms_and_refinement():
    cfg = config(*VERBS[0], "--mode", "independent", "--no-expressive", "--no-temporal", "--no-refine")
    assert cfg == replace(CPU_SEQUENCE, mode="independent", expressive=False, temporal=False, refine_enabled=False)


def test_evaluate_video_has_no_row_flags(capsys):
    with pytest.raises(SystemExit) as e:  # its six rows set mode and terms themselves
        build_parser().parse_args([*VERBS[1], "--no-expressive"])  # (--mode would abbreviate its --model)
    assert e.value.code == 2 and "--no-expressive" in capsys.readouterr().err


@pytest.mark.parametrize("verb", VERBS, ids=lambda v: v[0])
def test_help_shows_the_cpu_presets_values(verb):
    sub = next(a for a in build_parser()._actions if a.dest == "verb").choices[verb[0]]
    helps = {s: a.help for a in sub._actions for s in a.option_strings}
    assert helps["--first-batch"].startswith(f"joint vectors optimised together (default: {CPU_SEQUENCE.first.batch}")
    assert f"default: {CPU_SEQUENCE.next.iterations}, from CPU_SEQUENCE.next" in helps["--next-iters"]
    assert "(default: cpu)" in helps["--preset"] and "the preset's" in helps["--seed"]
