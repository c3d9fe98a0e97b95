"""The guided calibration: for each joint, jog its servo (or move it by hand) to zero, the lower and the upper
soft limit, and record each; the direction follows from which way the limits lie.

:class:`CalibrationWizard` is driven by text commands (``+``, ``-``, ``step N``, ``free``, ``hold``, ``set``,
``skip``) so the terminal verb and tests use the same logic. Servo positions here are raw units: the calibration
is what is being made.

A read that fails raises (``ServoTimeout``) before anything changes, so the same command can simply be typed
again; :meth:`CalibrationWizard.progress` is what is worth keeping when the session ends early.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from hardware import constants as C
from hardware.bus import ServoBus
from hardware.calibration import Calibration, JointCalibration, validate
from studio.sim.hand import Hand

STAGES = ("zero", "lower", "upper")
PROMPTS = {
    "zero": "move it to its zero pose (0 rad: the flat open hand)",
    "lower": "move it to the most negative angle it may safely reach",
    "upper": "move it to the most positive angle it may safely reach",
}


@dataclass
class WizardConfig:
    """How the wizard jogs."""

    step_units: int = 10  # size of one + / - step, servo units (≈ 2.4°)
    move_s: float = 0.2  # move time of each jog step
    margin_rad: float = 0.02  # recorded limits are pulled this far inside the URDF limits when beyond them
    min_span_rad: float = 0.1  # narrowest accepted range between the recorded limits


class CalibrationWizard:
    """Walks through every joint of ``hand``; ``start`` gives each joint's servo ID (and values for ``skip``)."""

    def __init__(self, bus: ServoBus, hand: Hand, start: Calibration, config: WizardConfig | None = None):
        self.bus, self.hand = bus, hand
        self.cfg = config or WizardConfig()
        self.start = validate(start, hand)
        self.done: list[JointCalibration] = []
        self.stage = 0
        self.record: dict[str, float] = {}
        self.notes: list[str] = []  # warnings (limits pulled inside the URDF)
        self.calibrated: list[str] = []  # joints finished with three 'set's (not skipped), in order
        self._goal: int | None = None

    @property
    def finished(self) -> bool:
        return len(self.done) == len(self.start.joints)

    @property
    def current(self) -> JointCalibration:
        return self.start.joints[len(self.done)]

    def prompt(self) -> str:
        if self.finished:
            return "all joints calibrated"
        j = self.current
        where = f"[{len(self.done) + 1}/{len(self.start.joints)}]"
        return f"{where} {j.name} (servo {j.servo_id}): {PROMPTS[STAGES[self.stage]]}"

    def execute(self, line: str) -> str:
        """Run one command; returns what to show next."""
        if self.finished:
            raise ValueError("calibration is complete; save it")
        words = line.strip().split()
        cmd = words[0].lower() if words else "set"
        sid = self.current.servo_id
        if cmd in ("+", "-"):
            here = self._goal if self._goal is not None else self.bus.read_position(sid)
            self._goal = min(max(here + (self.cfg.step_units if cmd == "+" else -self.cfg.step_units), 0), C.POS_UNITS)
            self.bus.move_batch({sid: self._goal}, self.cfg.move_s)
            return f"servo {sid} -> {self._goal}"
        if cmd == "step" and len(words) == 2:
            self.cfg.step_units = int(words[1])
            return f"step {self.cfg.step_units} units"
        if cmd == "free":
            self.bus.set_torque(False, [sid])
            self._goal = None
            return f"servo {sid} is limp: move it by hand, then 'set'"
        if cmd == "hold":
            self._goal = self.bus.read_position(sid)
            self.bus.move_batch({sid: self._goal}, self.cfg.move_s)
            return f"servo {sid} holds {self._goal}"
        if cmd == "set":
            self.record[STAGES[self.stage]] = float(self.bus.read_position(sid))
            self.stage += 1
            if self.stage == len(STAGES):
                self._finish_joint()
            return self.prompt()
        if cmd == "skip":
            self.done.append(self.current)
            self.stage, self.record, self._goal = 0, {}, None
            return self.prompt()
        raise ValueError(f"unknown command {line.strip()!r}: use + - 'step N' free hold set skip")

    def _finish_joint(self) -> None:
        j, r = self.current, self.record
        u = self.hand.joints[self.hand.joint_names.index(j.name)]
        direction = 1 if r["upper"] >= r["lower"] else -1
        lo = (r["lower"] - r["zero"]) * direction / C.UNITS_PER_RAD
        hi = (r["upper"] - r["zero"]) * direction / C.UNITS_PER_RAD
        lo2 = max(lo, min(u.lower + self.cfg.margin_rad, 0.0))  # inside the URDF, never past the zero pose
        hi2 = min(hi, max(u.upper - self.cfg.margin_rad, 0.0))
        if not lo2 <= 0.0 <= hi2 or hi2 - lo2 < self.cfg.min_span_rad:
            self.stage, self.record, self._goal = 0, {}, None
            raise ValueError(
                f"{j.name}: limits [{lo2:.3f}, {hi2:.3f}] rad around the zero are too narrow or exclude it; "
                "start this joint again: " + self.prompt()
            )
        if (lo2, hi2) != (lo, hi):
            self.notes.append(f"{j.name}: limits [{lo:.3f}, {hi:.3f}] rad moved inside URDF: [{lo2:.3f}, {hi2:.3f}]")
        self.done.append(replace(j, direction=direction, zero=r["zero"], lower=lo2, upper=hi2))
        self.calibrated.append(j.name)
        self.stage, self.record, self._goal = 0, {}, None

    def progress(self) -> Calibration | None:
        """The start calibration with every joint calibrated so far put in (a file to resume from with
        ``--start``, skipping those joints); None when no joint has been set yet."""
        if not self.calibrated:
            return None
        done = {j.name: j for j in self.done}
        return Calibration(tuple(done.get(j.name, j) for j in self.start.joints), self.hand.hash)

    def result(self) -> Calibration:
        """The new calibration (validated against the hand)."""
        if not self.finished:
            raise ValueError(f"{len(self.start.joints) - len(self.done)} joints still to calibrate")
        return validate(
            Calibration(tuple(self.done), self.hand.hash, self.start.roll, self.start.measured), self.hand
        )  # the rig kept
