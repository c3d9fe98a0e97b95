"""studio.cli.run_flags: one ``--preset`` with the same names and one set of budget flags on every verb that
optimises keyframes, each flag overriding one field of the preset only when given, defined once."""

from __future__ import annotations

from dataclasses import replace

import pytest

from studio.cli.main import build_parser
from studio.cli.run_flags import sequence_from_args
from studio.imitate.config import CPU_SEQUENCE, PAPER_SEQUENCE, PRESETS, STUDIO

VIDEO_VERBS = (
    ["imitate-video", "clip.gif", "--out", "o"],
    ["evaluate-video", "clip.gif", "--out", "o"],
    ["project", "run", "p.shadow"],
    ["demo", "--out", "o"],
)
STILL_VERBS = (["imitate", "t.png", "--out", "o"], ["evaluate", "t.png", "--out", "o"])
BUDGET = ["--preset", "paper", "--search-batch", "8", "--next-iterations", "7", "--refine-restarts", "3",
          "--candidates", "2"]  # fmt: skip


def config(*argv: str):
    return sequence_from_args(build_parser().parse_args(list(argv)))


def _sub(verb: list[str]):
    parser = next(a for a in build_parser()._actions if a.dest == "verb").choices[verb[0]]
    if verb[0] == "project":
        parser = next(a for a in parser._actions if a.dest == "project_verb").choices[verb[1]]
    return parser


@pytest.mark.parametrize("verb", VIDEO_VERBS, ids=lambda v: " ".join(v[:2]))
def test_no_flags_is_the_studio_preset_and_paper_keeps_every_size_not_given(verb):
    assert config(*verb) == CPU_SEQUENCE == PRESETS[STUDIO]
    assert config(*verb, "--preset", "paper") == PAPER_SEQUENCE
    cfg = config(*verb, *BUDGET)
    assert cfg.first == replace(PAPER_SEQUENCE.first, batch=8)
    assert cfg.next == replace(PAPER_SEQUENCE.next, iterations=7)
    assert cfg.refine == replace(PAPER_SEQUENCE.refine, restarts=3)
    assert cfg.candidates == 2 and cfg.mode == PAPER_SEQUENCE.mode
    swept = config(*verb, "--sweep-draws", "64", "--sweep-passes", "1")
    assert swept == replace(CPU_SEQUENCE, sweep=replace(CPU_SEQUENCE.sweep, draws=64, passes=1))
    one_order = config(*verb, "--no-joint-both-orders")  # the studio poses the keyframes in both orders
    assert CPU_SEQUENCE.joint.both_orders and one_order == replace(
        CPU_SEQUENCE, joint=replace(CPU_SEQUENCE.joint, both_orders=False)
    )


def test_every_verb_reads_the_same_flags_the_same_way():
    first = config(*VIDEO_VERBS[0], *BUDGET, "--seed", "5")
    for verb in VIDEO_VERBS[1:]:
        assert config(*verb, *BUDGET, "--seed", "5") == first
    still = ["--preset", "paper", "--search-batch", "8", "--refine-restarts", "3", "--candidates", "2", "--seed", "5"]
    for verb in STILL_VERBS:  # a still is searched as a keyframe from scratch: the same fields
        cfg = config(*verb, *still)
        assert (cfg.first, cfg.refine, cfg.candidates) == (first.first, first.refine, first.candidates)
    cfg = config(*VIDEO_VERBS[1], "--seed", "5")
    assert (cfg.first.seed, cfg.next.seed, cfg.refine.seed, cfg.sweep.seed) == (5, 5, 5, 5)


def test_video_verbs_set_mode_terms_and_refinement():
    for verb in (VIDEO_VERBS[0], VIDEO_VERBS[2]):
        cfg = config(*verb, "--mode", "independent", "--no-expressive", "--no-temporal", "--no-refine")
        assert cfg == replace(CPU_SEQUENCE, mode="independent", expressive=False, temporal=False, refine_enabled=False)


def test_stills_and_tables_have_no_flags_they_cannot_use(capsys):
    for argv in ([*VIDEO_VERBS[1], "--no-expressive"], [*STILL_VERBS[0], "--next-batch", "4"],
                 [*STILL_VERBS[1], "--mode", "independent"]):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            build_parser().parse_args(argv)
        assert e.value.code == 2


@pytest.mark.parametrize("verb", VIDEO_VERBS + STILL_VERBS, ids=lambda v: " ".join(v[:2]))
def test_help_shows_the_studio_presets_values_and_no_old_names(verb):
    helps = {s: a.help for a in _sub(verb)._actions for s in a.option_strings}
    assert helps["--search-batch"].startswith(f"joint vectors optimised together (default: {CPU_SEQUENCE.first.batch}")
    assert "(default: studio)" in helps["--preset"] and "the preset's" in helps["--seed"]
    assert not {"--method", "--first-batch", "--first-iters", "--search-iters", "--next-iters"} & set(helps)
    assert {"--clip-weights", "--no-clip"} <= set(helps) or verb[0] == "evaluate-video"
