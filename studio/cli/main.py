"""``shadow-studio <verb>``: the command-line face of the engine.

Each verb lives in a module that exposes ``register(subparsers)``: it adds its parser and sets ``func`` to a
function ``(args) -> int``. Errors users can meet (``StudioError``, ``ValueError``, missing files, bad flags, a full
disk or a name too long: :mod:`studio.cli.os_errors`, a word that is not UTF-8 text) are printed as one line on
stderr with exit code 2, never as a traceback. Any other exception is a bug: one line
``internal error: …`` and exit code 1; ``-v`` shows its traceback (and the traceback of a user error too).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
import traceback
from collections.abc import Iterable

from studio.cli.flags import CliParser
from studio.cli.os_errors import os_error_line
from studio.cli.runs import advice
from studio.cli.signals import hold_after_stop
from studio.errors import StudioError
from studio.targets.path_checks import check_text

# Modules that contribute verbs, in --help order.
VERB_MODULES = (
    "studio.cli.hand",
    "studio.cli.data",
    "studio.cli.train",
    "studio.cli.finetune",
    "studio.cli.evaluate",
    "studio.cli.imitate",
    "studio.cli.video",
    "studio.cli.servos",
    "studio.cli.jog",
    "studio.cli.rig",
    "studio.cli.live",
    "studio.cli.estop",
    "studio.cli.plan",
    "studio.cli.project",
    "studio.cli.demo",
    "studio.cli.lab",
)


# Each verb → the module that registers it (tests/test_cli.py checks it against VERB_MODULES): a command builds only
# its verb's parser, so `play`, `scan` or `render` start without importing torch (~2 s of the 3 s a full parser takes).
VERBS = {
    "render": "studio.cli.hand",
    "gen-urdf": "studio.cli.hand",
    "collect": "studio.cli.data",
    "train": "studio.cli.train",
    "finetune": "studio.cli.finetune",
    "evaluate": "studio.cli.evaluate",
    "evaluate-video": "studio.cli.evaluate",
    "train-inverse": "studio.cli.evaluate",
    "imitate": "studio.cli.imitate",
    "keyframes": "studio.cli.video",
    "imitate-video": "studio.cli.imitate",
    "emulate": "studio.cli.servos",
    "scan": "studio.cli.servos",
    "calibrate": "studio.cli.servos",
    "play": "studio.cli.servos",
    "jog": "studio.cli.jog",
    "calibrate-rig": "studio.cli.rig",
    "capture": "studio.cli.rig",
    "live": "studio.cli.live",
    "estop": "studio.cli.estop",
    "plan": "studio.cli.plan",
    "validate": "studio.cli.plan",
    "show-info": "studio.cli.plan",
    "export-csv": "studio.cli.plan",
    "project": "studio.cli.project",
    "demo": "studio.cli.demo",
    "lab": "studio.cli.lab",
}


def verb_modules_for(argv: list[str]) -> tuple[str, ...]:
    """The modules a command line needs: its verb's (the first word not starting with "-"; the top level has only
    flags without values), or all of them for ``--help``, no verb or an unknown one (argparse then lists them)."""
    verb = next((a for a in argv if not a.startswith("-")), None)
    return (VERBS[verb],) if verb in VERBS else VERB_MODULES


def build_parser(verb_modules: Iterable[str] = VERB_MODULES) -> argparse.ArgumentParser:
    """The ``shadow-studio`` parser with the verbs of ``verb_modules`` (module names, each with ``register``)."""
    parser = CliParser(
        prog="shadow-studio",
        description="Shadow Studio: make a 21-DoF robot hand perform shadow shows.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages and show tracebacks")
    sub = parser.add_subparsers(title="verbs", dest="verb", metavar="<verb>")
    for name in verb_modules:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None, verb_modules: Iterable[str] | None = None) -> int:
    """Run ``shadow-studio`` with ``argv`` (default ``sys.argv[1:]``); returns the exit code. ``verb_modules``
    None: the modules the command line needs (:func:`verb_modules_for`). Without ``argv`` this is the process's
    own command: a verb a stop signal ended keeps ignoring later ones until the process exits."""
    if argv is None:
        hold_after_stop()
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    parser = build_parser(verb_modules_for(argv) if verb_modules is None else verb_modules)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s"
    )
    if not getattr(args, "func", None):
        parser.print_help()
        return 0
    try:
        check_text(argv, "name")  # a word in another encoding fails at the start, not when printed at the end
        return int(args.func(args) or 0)
    except (StudioError, ValueError, FileNotFoundError, IsADirectoryError, PermissionError) as e:
        if args.verbose:
            traceback.print_exc()
        print(f"shadow-studio {args.verb}: error: {e}{advice(e)}", file=sys.stderr)
        return 2
    except OSError as e:  # a full disk, a name too long...: one line naming the file; any other errno is a bug
        line = os_error_line(e)
        if line is None:
            return _internal_error(args, e)
        if args.verbose:
            traceback.print_exc()
        print(f"shadow-studio {args.verb}: error: {line}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as e:  # Ctrl-C, or SIGTERM/SIGHUP where a verb handles them (studio.cli.signals)
        print(f"shadow-studio {args.verb}: interrupted{f' by {e}' if str(e) else ''}", file=sys.stderr)
        return getattr(e, "exit_code", 130)
    except Exception as e:  # a bug: one line, or the traceback with -v
        return _internal_error(args, e)


def _internal_error(args: argparse.Namespace, e: Exception) -> int:
    """A bug: one line, or the traceback with -v; exit code 1."""
    if args.verbose:
        traceback.print_exc()
        return 1
    message = f"{type(e).__name__}: {e}".replace("\n", " ")
    print(f"shadow-studio {args.verb}: internal error: {message} (run with -v for the traceback)", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
