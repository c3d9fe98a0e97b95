"""Command-line flags derived from config dataclasses: a flag's type, default, help and range come from the field.

A config field is written once (DESIGN §5.2). Its trailing comment is the flag's help, and the comment may end
with the range of accepted values in interval notation (``∞`` or ``inf`` for an open end)::

    @dataclass(frozen=True)
    class SearchConfig:
        batch: int = 256  # joint vectors optimised together [1, ∞)
        lr: float = 0.05  # Adam step size on the unconstrained parameters φ (0, ∞)

Then a verb adds flags for the fields it exposes and builds the config back from the parsed arguments::

    add_config_flags(p, SearchConfig, ("batch", "iterations"), prefix="search-", base=CPU_SEARCH,
                     base_name="CPU_SEARCH", aliases={"iterations": "iters"})
    # → --search-batch N (default 32, from CPU_SEARCH), --search-iterations/--search-iters N
    search = config_from_args(args, SearchConfig, prefix="search-", base=CPU_SEARCH, seed=args.seed)

A value outside the range is an argparse error: one line on stderr, exit code 2 (:class:`CliParser`). For a config
whose source does not state ranges, ``ranges={"n": "[1, ∞)"}`` gives them at the call. ``bool`` fields become
``--flag/--no-flag``; ``X | None`` fields take an ``X`` (None stays reachable only through the default or a
dedicated flag, as ``--otsu`` sets ``TargetConfig.threshold = None``). :func:`ranged` types a flag that mirrors no
config field (``--threads``) with the same range rules.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import io
import math
import re
import sys
import textwrap
import tokenize
import types
import typing
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

SEED_RANGE = "[0, 4294967295]"  # a seed flag's range: numpy and torch take any 32-bit unsigned seed
_RANGE = re.compile(r"\s*([\[(])\s*([^,\[\]()]+?)\s*,\s*([^,\[\]()]+?)\s*([\])])\s*$")


class CliParser(argparse.ArgumentParser):
    """An argument parser whose errors are one line on stderr (``PROG: error: …``), exit code 2. Flags are never
    abbreviated (``--mode`` must not quietly mean ``--model``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> typing.NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


@dataclasses.dataclass(frozen=True)
class Range:
    """An interval of accepted values: ``[lo, hi]`` with each end closed or open (±inf for no bound)."""

    lo: float
    hi: float
    lo_closed: bool = True
    hi_closed: bool = True

    @classmethod
    def parse(cls, text: str) -> Range | None:
        """``"[1, ∞)"`` → ``Range(1, inf, True, False)``; None when ``text`` is not an interval."""
        m = _RANGE.fullmatch(text.strip())
        if not m:
            return None
        try:
            lo, hi = _bound(m.group(2)), _bound(m.group(3))
        except ValueError:
            return None
        return cls(lo, hi, m.group(1) == "[", m.group(4) == "]") if lo <= hi else None

    def __contains__(self, x: float) -> bool:
        above = x >= self.lo if self.lo_closed else x > self.lo
        below = x <= self.hi if self.hi_closed else x < self.hi
        return bool(above and below)

    def __str__(self) -> str:
        return f"{'[' if self.lo_closed else '('}{_num(self.lo)}, {_num(self.hi)}{']' if self.hi_closed else ')'}"

    def describe(self) -> str:
        """The range in words a user reads in an error: ``≥ 1``, ``> 0``, ``in [0, 255)``."""
        if math.isinf(self.hi) and not math.isinf(self.lo):
            return f"{'≥' if self.lo_closed else '>'} {_num(self.lo)}"
        if math.isinf(self.lo) and not math.isinf(self.hi):
            return f"{'≤' if self.hi_closed else '<'} {_num(self.hi)}"
        return f"in {self}"


def _bound(text: str) -> float:
    t = text.strip().replace("−", "-")
    if t in ("∞", "+∞", "inf", "+inf"):
        return math.inf
    if t in ("-∞", "-inf"):
        return -math.inf
    return float(t)


def _num(x: float) -> str:
    if math.isinf(x):
        return "∞" if x > 0 else "-∞"
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def ranged(kind: type, rng: Range | str | None = None) -> Callable[[str], Any]:
    """An argparse ``type=`` for ``int`` or ``float`` values within ``rng`` (a :class:`Range` or its text).

    Floats must be finite numbers. A bad value raises ``argparse.ArgumentTypeError`` with a one-line reason.
    """
    if kind not in (int, float):
        raise TypeError(f"ranged() types int or float flags, not {kind!r}")
    rng = Range.parse(rng) if isinstance(rng, str) else rng
    noun = "a whole number" if kind is int else "a number"

    def convert(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {noun}, got {text!r}") from None
        if kind is float and not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
        if rng is not None and value not in rng:
            raise argparse.ArgumentTypeError(f"must be {rng.describe()}, got {text}")
        return value

    convert.__name__ = kind.__name__
    return convert


@dataclasses.dataclass(frozen=True)
class FieldDoc:
    """What a config field's trailing comment says: the help text and the range it ends with (if any)."""

    help: str
    range: Range | None = None


@functools.cache
def field_docs(cls: type) -> dict[str, FieldDoc]:
    """``{field name: FieldDoc}`` from the trailing ``# comment`` of each field in ``cls``'s source."""
    source = textwrap.dedent(inspect.getsource(cls))
    comments: dict[int, str] = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            comments.setdefault(tok.start[0], tok.string.lstrip("#").strip())
    node = next(n for n in ast.parse(source).body if isinstance(n, ast.ClassDef))
    out: dict[str, FieldDoc] = {}
    for stmt in node.body:
        if isinstance(stmt, ast.AnnAssign) and isinstance(stmt.target, ast.Name):
            lines = range(stmt.lineno, (stmt.end_lineno or stmt.lineno) + 1)
            text = next((comments[i] for i in lines if i in comments), "")
            m = _RANGE.search(text)
            rng = Range.parse(m.group(0)) if m else None
            out[stmt.target.id] = FieldDoc(text[: m.start()].rstrip(" ;,") if rng else text, rng)
    return out


def _flag_type(cls: type, name: str) -> type:
    """The flag's value type from the field's annotation (``X | None`` → ``X``)."""
    module = sys.modules.get(cls.__module__)
    hint = typing.get_type_hints(cls, vars(module) if module else None)[name]
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        hint = args[0] if len(args) == 1 else hint
    if hint in (int, float, str, bool, Path):
        return hint
    raise TypeError(f"{cls.__name__}.{name}: a field of type {hint} has no command-line flag")


def dest_of(prefix: str, name: str) -> str:
    """The argparse ``dest`` of field ``name`` under ``prefix`` (``"search-"``, ``"batch"`` → ``search_batch``)."""
    return (prefix + name).replace("-", "_")


def add_config_flags(
    parser: argparse.ArgumentParser | argparse._ArgumentGroup,
    cls: type,
    fields: Iterable[str] | None = None,
    prefix: str = "",
    base: Any = None,
    base_name: str | None = None,
    aliases: Mapping[str, str] | None = None,
    ranges: Mapping[str, str | Range] | None = None,
) -> None:
    """Add ``--PREFIX-FIELD`` flags for ``fields`` of the dataclass ``cls`` (all fields when None).

    Defaults come from ``base`` (an instance, e.g. the ``CPU_SEARCH`` preset, named ``base_name`` in the help) or
    the class; help and range from the field's comment (:func:`field_docs`), or ``ranges`` where the source gives
    none. ``aliases`` adds a second spelling (``{"iterations": "iters"}`` → ``--search-iters`` too).
    """
    docs = field_docs(cls)
    known = {f.name: f for f in dataclasses.fields(cls)}
    defaults = base if base is not None else cls()
    for name in fields if fields is not None else list(known):
        if name not in known:
            raise KeyError(f"{cls.__name__} has no field {name!r}")
        doc = docs.get(name, FieldDoc(""))
        rng = (ranges or {}).get(name, doc.range)
        rng = Range.parse(rng) if isinstance(rng, str) else rng
        kind = _flag_type(cls, name)
        default = getattr(defaults, name)
        names = ["--" + (prefix + name).replace("_", "-")]
        if aliases and name in aliases:
            names.append("--" + (prefix + aliases[name]).replace("_", "-"))
        where = f", from {base_name}" if base is not None and base_name else ""
        shown = "on" if default is True else "off" if default is False else "unset" if default is None else default
        text = f"{doc.help or name.replace('_', ' ')} (default: {shown}{where}".replace("%", "%%")
        text += f"; {rng.describe()})" if rng else ")"
        common = {"dest": dest_of(prefix, name), "default": default, "help": text}
        parser.set_defaults(_config_dests=(parser.get_default("_config_dests") or frozenset()) | {common["dest"]})
        if kind is bool:
            parser.add_argument(*names, action=_GivenBool, **common)
        elif kind in (int, float):
            metavar = "N" if kind is int else "X"
            parser.add_argument(*names, action=_Given, type=ranged(kind, rng), metavar=metavar, **common)
        else:
            parser.add_argument(*names, action=_Given, type=kind, metavar="VALUE", **common)


class _Given(argparse.Action):
    """Store the value and remember that the flag was given (:func:`given`)."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        setattr(namespace, self.dest, values)
        namespace._given = getattr(namespace, "_given", frozenset()) | {self.dest}


class _GivenBool(argparse.BooleanOptionalAction):
    def __call__(self, parser, namespace, values, option_string=None) -> None:
        super().__call__(parser, namespace, values, option_string)
        namespace._given = getattr(namespace, "_given", frozenset()) | {self.dest}


def given(args: argparse.Namespace, dest: str) -> bool:
    """Whether the config flag with ``dest`` was on the command line (not just its default)."""
    return dest in getattr(args, "_given", frozenset())


def config_from_args(args: argparse.Namespace, cls: type, prefix: str = "", base: Any = None, **overrides: Any):
    """``base`` (or ``cls()``) with every field that :func:`add_config_flags` gave a ``--PREFIX-FIELD`` flag set from
    ``args``, then ``overrides`` (e.g. a ``seed`` shared by several configs)."""
    dests = getattr(args, "_config_dests", frozenset())
    values = {
        f.name: getattr(args, dest_of(prefix, f.name))
        for f in dataclasses.fields(cls)
        if dest_of(prefix, f.name) in dests
    }
    return dataclasses.replace(base if base is not None else cls(), **(values | overrides))
