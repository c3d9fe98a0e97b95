"""studio.cli.flags: flags take their type, default, help and range from the config dataclass, never typed twice."""

from __future__ import annotations

import argparse
import importlib.util
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from studio.cli.flags import CliParser, Range, add_config_flags, config_from_args, field_docs, given, ranged
from studio.imitate.config import CPU_SEARCH, SearchConfig

THROWAWAY = '''
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Knobs:
    """A throwaway config."""

    count: int = {count}  # how many things [1, ∞)
    rate: float = 0.5  # a fraction (0, 1]
    name: str = "x"  # what it is called
    loud: bool = False  # shout about it
    limit: float | None = None  # an optional cap [0, 10]
'''


def _load(tmp_path: Path, name: str, count: int):
    path = tmp_path / f"{name}.py"
    path.write_text(THROWAWAY.format(count=count))
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses resolve the module of the class
    spec.loader.exec_module(module)
    return module.Knobs


def _parser(cls, **kw) -> argparse.ArgumentParser:
    p = CliParser(prog="prog")
    add_config_flags(p, cls, **kw)
    return p


def _help(p: argparse.ArgumentParser, flag: str) -> str:
    return p._option_string_actions[flag].help


def test_changing_a_dataclass_default_changes_the_flag(tmp_path: Path) -> None:
    seven, eleven = _load(tmp_path, "knobs_seven", 7), _load(tmp_path, "knobs_eleven", 11)
    assert _parser(seven).parse_args([]).count == 7
    assert _parser(eleven).parse_args([]).count == 11
    p = _parser(eleven)
    assert _help(p, "--count") == "how many things (default: 11; ≥ 1)"
    assert _help(p, "--rate") == "a fraction (default: 0.5; in (0, 1])"
    assert _help(p, "--no-loud") == "shout about it (default: off)"
    args = _parser(eleven).parse_args(["--count", "3", "--loud", "--name", "y", "--limit", "2.5"])
    cfg = config_from_args(args, eleven)
    assert (cfg.count, cfg.loud, cfg.name, cfg.limit, cfg.rate) == (3, True, "y", 2.5, 0.5)


def test_field_docs_read_the_trailing_comments(tmp_path: Path) -> None:
    docs = field_docs(_load(tmp_path, "knobs_docs", 1))
    assert docs["count"].help == "how many things" and docs["count"].range == Range(1, float("inf"), True, False)
    assert docs["name"].help == "what it is called" and docs["name"].range is None
    assert docs["limit"].range == Range(0, 10, True, True)
    # the real configs: every field has its comment
    assert all(d.help for d in field_docs(SearchConfig).values())
    assert field_docs(SearchConfig)["batch"].range == Range.parse("[1, 2048]")


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--count", "0"], "argument --count: must be ≥ 1, got 0"),
        (["--count", "2.5"], "argument --count: expected a whole number, got '2.5'"),
        (["--rate", "0"], "argument --rate: must be in (0, 1], got 0"),
        (["--rate", "nan"], "argument --rate: expected a finite number, got 'nan'"),
        (["--limit", "11"], "argument --limit: must be in [0, 10], got 11"),
    ],
)
def test_out_of_range_is_a_one_line_argparse_error(tmp_path: Path, capsys, argv, words) -> None:
    p = _parser(_load(tmp_path, "knobs_range", 1))
    with pytest.raises(SystemExit) as e:
        p.parse_args(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err and err.startswith("prog: error: "), err


def test_preset_is_the_default_and_named_in_the_help() -> None:
    p = _parser(SearchConfig, fields=("batch", "iterations"), prefix="search-", base=CPU_SEARCH,
                base_name="CPU_SEARCH", aliases={"iterations": "iters"})  # fmt: skip
    assert (
        _help(p, "--search-batch")
        == f"joint vectors optimised together (default: {CPU_SEARCH.batch}, from CPU_SEARCH; in [1, 2048])"
    )
    assert _help(p, "--search-iters") is _help(p, "--search-iterations")
    args = p.parse_args(["--search-iters", "9"])
    cfg = config_from_args(args, SearchConfig, prefix="search-", base=CPU_SEARCH, seed=4)
    assert cfg == SearchConfig(batch=CPU_SEARCH.batch, iterations=9, lr=CPU_SEARCH.lr, seed=4)
    assert given(args, "search_iterations") and not given(args, "search_batch")


def test_only_flagged_fields_are_read_back() -> None:
    @dataclass(frozen=True)
    class Two:
        out: str = "a"
        seed: int = 0

    args = argparse.Namespace(out="elsewhere", seed=5)  # same names, but no flag of Two made them
    assert config_from_args(args, Two) == Two()


def test_ranges_for_configs_whose_source_gives_none() -> None:
    from studio.learn.config import CollectConfig

    p = _parser(CollectConfig, fields=("n",), ranges={"n": "[1, ∞)"})
    with pytest.raises(SystemExit):
        p.parse_args(["--n", "0"])
    assert config_from_args(p.parse_args(["--n", "12"]), CollectConfig).n == 12


def test_ranged_and_range_text() -> None:
    assert ranged(int, "[1, ∞)")("3") == 3
    with pytest.raises(argparse.ArgumentTypeError, match="must be ≥ 1, got 0"):
        ranged(int, "[1, ∞)")("0")
    with pytest.raises(argparse.ArgumentTypeError, match="must be > 0"):
        ranged(float, "(0, inf)")("0")
    assert str(Range.parse("(0, 1]")) == "(0, 1]" and 1 in Range.parse("(0, 1]") and 0 not in Range.parse("(0, 1]")
    assert Range.parse("(B, 21)") is None and Range.parse("[3, 1]") is None
    with pytest.raises(KeyError):
        _parser(SearchConfig, fields=("nope",))
    with pytest.raises(TypeError):
        _parser(__import__("studio.sim.shadow", fromlist=["Rig"]).Rig, fields=("light",))
