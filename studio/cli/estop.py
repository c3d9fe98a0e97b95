"""``shadow-studio estop [--reset | --status]``: the e-stop latch that every process of the studio obeys.

Plain ``estop`` latches it (or leaves the latch that is already set, which says what pressed it first) and says so:
every process open on the servos (``play``, ``jog``, the notebook's panels) halts them within a tick, and nothing
moves again until ``estop --reset``. ``--status`` only shows it (exit code 1 while latched, 0 when clear). The latch
is a file (:mod:`hardware.estop`: ``$SHADOW_STUDIO_ESTOP``, else ``estop.json`` in the studio's home folder), one for
every port and the emulator alike.
"""

from __future__ import annotations

import argparse

from hardware.estop import clear_latch, latch_path, read_latch, set_latch


def cmd_estop(args: argparse.Namespace) -> int:
    path = latch_path()
    if args.reset:
        cleared = clear_latch(path)
        if cleared is None:
            print(f"the e-stop was not latched ({path}): nothing to reset")
        else:
            print(f"e-stop reset (it was {cleared.describe()}): the servos may move again")
        return 0
    if args.status:
        held = read_latch(path)
        print(f"the e-stop is latched ({held.describe()}); `shadow-studio estop --reset` clears it" if held else
              f"the e-stop is not latched ({path})")  # fmt: skip
        return 1 if held else 0
    held = set_latch("shadow-studio estop", path)
    print(f"E-STOP latched ({held.describe()}): every process halts the servos and nothing moves until "
          "`shadow-studio estop --reset`")  # fmt: skip
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("estop", help="latch the e-stop for every process (--reset clears it, --status shows it)")
    what = p.add_mutually_exclusive_group()
    what.add_argument("--reset", action="store_true", help="clear the e-stop: the servos may move again")
    what.add_argument("--status", action="store_true", help="only show whether it is latched (exit code 1 if so)")
    p.set_defaults(func=cmd_estop)
