"""Verb ``jog``: move joints one at a time from the terminal (``hardware.jog.Jog``; type ``help``).

It opens the servos through :func:`studio.cli.servos.session_for` and fails safe as the other servo verbs do (DESIGN
§5.13): Ctrl-C, SIGTERM and SIGHUP stop every servo and leave torque held, with one line and exit code 128 + the
signal; a lost port (``BusError``) ends it with one line and exit code 2 (through ``main``); a servo that misses a
read or a refused command is answered with ``?`` and the jog carries on. What was typed and answered is written to
``--log`` (default ``<studio home>/logs/jog-<time>.txt``) however the jog ended once the servos were open.
"""

from __future__ import annotations

import sys
from datetime import datetime
from pathlib import Path

import numpy as np

from hardware.calibration import load_calibration
from hardware.errors import EStopLatched, ProtocolError, ServoTimeout
from hardware.jog import HELP, Jog
from studio.atomic import write_text
from studio.cli.runs import advice
from studio.cli.servo_logs import log_path, save_log
from studio.cli.servos import bus_args, session_for
from studio.cli.signals import exit_code, stop_on_signals
from studio.sim.hand import load_hand


def cmd_jog(args) -> int:
    hand = load_hand()
    cal = load_calibration(args.calibration, hand)
    started = datetime.now().astimezone().isoformat(timespec="seconds")
    journal = [f"# shadow-studio jog on {args.port}, started {started}"]

    def say(line: str, typed: bool = False) -> None:  # to the log, then to the terminal (not what was typed)
        stamp = datetime.now().strftime("%H:%M:%S.%f")[:-3]
        journal.extend(f"{stamp} {'>' if typed else ' '} {part}" for part in line.splitlines())
        if not typed:
            print(line)

    log_to, code, stop, session = log_path(args.log, "jog", ".txt"), 0, None, None
    try:
        with stop_on_signals("jog") as caught, session_for(args, cal) as session:
            try:
                jog = Jog(session.bus, cal, home_pose=hand.rest_pose())
                print(HELP)
                silent = [i for i, q in zip(cal.ids, jog.target) if np.isnan(q)]
                if silent:
                    say(f"? servos {silent} did not answer: check their cables; their angles show as ?")
                if session.bus.estop_latched:
                    say(f"? {session.bus.latch_message()} (type reset to clear it)")
                say(jog.status())
                for line in sys.stdin:
                    say(line.strip(), typed=True)
                    if line.strip().lower() in ("q", "quit", "exit"):
                        break
                    try:
                        say(jog.execute(line))
                    except (ValueError, ServoTimeout, ProtocolError, EStopLatched) as e:  # BusError ends the verb
                        say(f"? {e}{advice(e)}")
            except KeyboardInterrupt as e:  # Ctrl-C, SIGTERM, SIGHUP: the session's close stops every servo
                stop, code = e, exit_code(caught[0] if caught else e)
            report = session.close()  # inside: a later signal is ignored until the verb has said how it ended
            end = f"stopped by {stop or 'Ctrl-C'}: {report.message}" if stop is not None else ""
            if end:
                print(f"shadow-studio jog: {end}", file=sys.stderr)
            journal.append(f"end: {end or report.message}")
    finally:  # however jog ended once the servos were open (a lost port too): what was typed and answered
        if session is not None:
            save_log(lambda path: write_text(path, "\n".join(journal) + "\n"), log_to, args.log, "jog log")
    return code


def register(sub) -> None:
    p = sub.add_parser("jog", help="move joints one at a time from the terminal (type help)")
    bus_args(p)
    p.add_argument("--calibration", type=Path, help="calibration YAML (default: assets/calibration.yaml)")
    p.add_argument("--log", type=Path, help="save what was typed and answered to this text file (default: "
                   "<studio home>/logs/jog-<time>.txt)")  # fmt: skip
    p.set_defaults(func=cmd_jog)
