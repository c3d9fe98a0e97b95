"""Jogging: move one joint at a time through the calibration and the safety layer.

:class:`Jog` holds the logic (select a joint, step ±, go to an angle, home, torque, read, e-stop) and is driven
by method calls or by text commands through :meth:`Jog.execute`; the terminal verb and the notebook's jog panel
are thin faces of it. Every move is clipped to the soft limits and paced at ``speed_rad_s``.

Failing safe (DESIGN §5.13): ``stop`` latches the bus's e-stop, for every process (its file, :mod:`hardware.estop`):
every later move raises ``EStopLatched`` until ``reset`` (or ``shadow-studio estop --reset``); a typed angle must be
finite; a servo that misses a read leaves its angle unknown (NaN) instead of ending the session, and a move of
a joint whose angle is unknown reads it first (``ServoTimeout`` if it still does not answer).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from hardware.bus import ServoBus
from hardware.calibration import Calibration
from hardware.safety import clip_command, move_time

HELP = """commands:
  j NAME|INDEX     select a joint              + / -          step the joint by the step size
  step DEG         set the step size           go DEG         move the joint to an angle (degrees)
  home             all joints to their rest    read           measured angles of every joint
  on / off         torque on / off (all)       stop           e-stop: halt every servo now (latches)
  reset            clear the e-stop            joints         list joints
  help / quit"""


@dataclass
class JogConfig:
    """How jog moves behave."""

    step_rad: float = math.radians(3.0)  # size of one + / - step
    speed_rad_s: float = 0.8  # joint speed of jog moves
    min_move_s: float = 0.05  # shortest move time sent
    release_on_estop: bool = False  # e-stop also releases torque (True) or holds the pose (False)


@dataclass(frozen=True)
class JogMove:
    """One move as sent."""

    joint: str  # joint moved (or "all")
    requested: float  # rad asked for (NaN for multi-joint moves)
    sent: float  # rad actually commanded after clipping
    clipped: bool  # the request lay beyond a soft limit
    duration_s: float  # move time sent


class Jog:
    """Jog a hand on a connected bus. ``target (J,) rad`` is the pose last commanded, calibration order (NaN: a
    servo whose angle is not known yet because it did not answer)."""

    def __init__(
        self,
        bus: ServoBus,
        calibration: Calibration,
        *,
        config: JogConfig | None = None,
        home_pose: np.ndarray | None = None,
    ):
        self.bus, self.cal = bus, calibration
        self.cfg = config or JogConfig()
        self.home_pose = np.zeros(len(calibration.ids)) if home_pose is None else np.asarray(home_pose, float)
        self.index = 0
        self.target = self.read_array(strict=False)

    @property
    def joint(self) -> str:
        return self.cal.joint_names[self.index]

    def select(self, joint: str | int) -> str:
        """Select by name or index; returns the name."""
        names = self.cal.joint_names
        if isinstance(joint, str) and joint.lstrip("-").isdigit():
            joint = int(joint)
        if isinstance(joint, int):
            if not 0 <= joint < len(names):
                raise ValueError(f"joint index must be 0..{len(names) - 1}")
            self.index = joint
        elif joint in names:
            self.index = names.index(joint)
        else:
            raise ValueError(f"unknown joint {joint!r}; joints: {', '.join(names)}")
        return self.joint

    def read_array(self, strict: bool = True) -> np.ndarray:
        """(J,) measured angles, rad. A servo that does not answer raises ``ServoTimeout`` (or ``ProtocolError``
        for a garbled answer); with ``strict=False`` its angle reads NaN instead."""
        got = self.bus.read_positions(self.cal.ids) if strict else self.bus.read_back(self.cal.ids)
        return self.cal.to_rad(np.array([np.nan if got[i] is None else got[i] for i in self.cal.ids], float))

    def read(self) -> dict[str, float]:
        """``{joint: rad}`` measured."""
        return dict(zip(self.cal.joint_names, self.read_array().tolist()))

    def _known(self, j: int) -> float:
        """Joint ``j``'s last commanded angle, read from the servo if not known yet (raises ServoTimeout)."""
        if np.isnan(self.target[j]):
            one = np.full(len(self.cal.ids), float(self.bus.read_position(self.cal.ids[j])))
            self.target[j] = float(np.clip(self.cal.to_rad(one)[j], self.cal.lower[j], self.cal.upper[j]))
        return float(self.target[j])

    def go(self, angle_rad: float) -> JogMove:
        """Move the selected joint to ``angle_rad`` (clipped to its soft limits); ``ValueError`` for NaN or ±inf."""
        if not math.isfinite(angle_rad):
            raise ValueError(f"cannot move {self.joint} to {angle_rad} rad: give a finite angle")
        j = self.index
        self._known(j)
        want = self.target.copy()
        want[j] = angle_rad
        c = clip_command(want, None, self.cal.lower, self.cal.upper, np.inf)
        dur = move_time(c.sent[j] - self.target[j], self.cfg.speed_rad_s, self.cfg.min_move_s)
        self.bus.move_batch({self.cal.ids[j]: self.cal.to_units(c.sent)[j]}, dur)
        self.target[j] = c.sent[j]
        return JogMove(self.joint, float(angle_rad), float(c.sent[j]), bool(c.at_limit[j]), dur)

    def step(self, sign: int) -> JogMove:
        """Step the selected joint by ``sign`` × the step size."""
        return self.go(self._known(self.index) + math.copysign(self.cfg.step_rad, sign))

    def home(self) -> JogMove:
        """Move every joint to the home pose (clipped), batched, at jog speed."""
        return self.go_pose(self.home_pose)

    def go_pose(self, theta: np.ndarray) -> JogMove:
        """Move every joint to ``theta (J,) rad`` (calibration order, clipped to the soft limits), batched, ramped
        at jog speed: one move whose time is the largest joint's distance over ``speed_rad_s``."""
        c = clip_command(np.asarray(theta, float), None, self.cal.lower, self.cal.upper, np.inf)
        delta = np.where(np.isnan(self.target), self.cal.upper - self.cal.lower, c.sent - self.target)  # unknown:
        dur = move_time(delta, self.cfg.speed_rad_s, self.cfg.min_move_s)  # pace as if from the far limit
        units = self.cal.to_units(c.sent)
        self.bus.write_positions(dict(zip(self.cal.ids, units)), dur)
        self.target = c.sent.copy()
        return JogMove("all", float("nan"), float("nan"), c.any, dur)

    def torque(self, on: bool) -> None:
        """Torque on (holding the measured pose) or off (limp) for every servo."""
        if on:
            self.target = np.clip(self.read_array(), self.cal.lower, self.cal.upper)
            self.bus.write_positions(dict(zip(self.cal.ids, self.cal.to_units(self.target))), self.cfg.min_move_s)
        self.bus.set_torque(on, self.cal.ids)

    def estop(self) -> bool:
        """Latch the bus's e-stop (for every process): halt every servo (broadcast), release torque if configured;
        every later move is refused until :meth:`reset`. Never raises; returns whether the halt reached the bus."""
        return self.bus.estop(release_torque=self.cfg.release_on_estop, by="jog")

    def reset(self) -> None:
        """Clear the e-stop (for every process: wherever it was pressed); the target becomes the measured pose
        (where the e-stop left each servo). ``EStopResetFailed`` when its file cannot be removed."""
        self.bus.reset_estop()
        here = self.read_array(strict=False)
        self.target = np.where(np.isnan(here), self.target, np.clip(here, self.cal.lower, self.cal.upper))

    def execute(self, line: str) -> str:
        """Run one text command; returns the line to show (``ValueError`` for bad input)."""
        words = line.strip().split()
        if not words:
            return self.status()
        cmd, args = words[0].lower(), words[1:]
        if cmd in ("+", "-"):
            return self._say(self.step(1 if cmd == "+" else -1))
        if cmd == "j" and args:
            self.select(args[0])
            return self.status()
        if cmd == "step" and args:
            self.cfg.step_rad = math.radians(_degrees(args[0], "step", positive=True))
            return f"step {args[0]} deg"
        if cmd == "go" and args:
            return self._say(self.go(math.radians(_degrees(args[0], "go"))))
        if cmd == "home":
            return self._say(self.home())
        if cmd in ("on", "off"):
            self.torque(cmd == "on")
            return f"torque {cmd}"
        if cmd == "read":
            q = self.read_array(strict=False)
            text = "  ".join(f"{n}=" + ("?" if np.isnan(v) else f"{math.degrees(v):.1f}") for n, v in
                             zip(self.cal.joint_names, q))  # fmt: skip
            silent = [i for i, v in zip(self.cal.ids, q) if np.isnan(v)]
            return text + (f"  (servos {silent} did not answer: check their cables)" if silent else "")
        if cmd in ("stop", "estop", "e"):
            if not self.estop():
                return "E-STOP latched, but the halt did not reach the bus: cut the servos' power"
            torque = ", torque released" if self.cfg.release_on_estop else ", holding"
            return f"E-STOP: servos halted{torque}; type reset to move again"
        if cmd == "reset":
            self.reset()
            return "e-stop reset: " + self.status()
        if cmd == "joints":
            return "  ".join(f"{k}:{n}" for k, n in enumerate(self.cal.joint_names))
        if cmd in ("help", "?", "h"):
            return HELP
        raise ValueError(f"unknown command {line.strip()!r}; type help")

    def status(self) -> str:
        j = self.index
        lo, hi = math.degrees(self.cal.lower[j]), math.degrees(self.cal.upper[j])
        now = "?" if np.isnan(self.target[j]) else f"{math.degrees(self.target[j]):.1f}"
        return f"[{j}] {self.joint} (servo {self.cal.ids[j]}): {now} deg in [{lo:.1f}, {hi:.1f}]"

    def _say(self, m: JogMove) -> str:
        note = "  (clipped to soft limit)" if m.clipped else ""
        if m.joint == "all":
            return f"home in {m.duration_s:.2f} s{note}"
        return f"{m.joint} -> {math.degrees(m.sent):.1f} deg in {m.duration_s:.2f} s{note}"


def _degrees(text: str, command: str, positive: bool = False) -> float:
    """A typed angle in degrees: a finite number (above 0 when ``positive``), else ``ValueError`` saying so."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or (positive and value <= 0):
        kind = "a number of degrees above 0" if positive else "a finite number of degrees"
        raise ValueError(f"{command} {text}: give {kind}, e.g. {command} 10")
    return value
