"""``shadow-studio <verb>``: the command-line face of the engine.

Each verb lives in a module that exposes ``register(subparsers)``: it adds its parser and sets ``func`` to a
function ``(args) -> int``. Errors users can meet (``StudioError``, ``ValueError``, missing files) are printed as
one line on stderr with exit code 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys

from studio.errors import StudioError

# Modules that contribute verbs, in --help order.
VERB_MODULES = (
    "studio.cli.hand",
    "studio.cli.data",
    "studio.cli.train",
    "studio.cli.evaluate",
    "studio.cli.imitate",
    "studio.cli.servos",
    "studio.cli.plan",
)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="shadow-studio",
        description="Shadow Studio: make a 21-DoF robot hand perform shadow shows.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(title="verbs", dest="verb", metavar="<verb>")
    for name in VERB_MODULES:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        return int(args.func(args) or 0)
    except (StudioError, ValueError, FileNotFoundError, IsADirectoryError, PermissionError) as e:
        print(f"shadow-studio {args.verb}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"shadow-studio {args.verb}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
