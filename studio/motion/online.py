"""Online jerk-limited motion: every tick, Ruckig steps from the current state toward the newest target pose.

The live mode moves the hand toward a target pose that may change at any 25 ms tick (40 Hz). Offline planning
(:mod:`studio.motion.timing`) times a whole path once; here :class:`OnlineMotion` keeps the commanded state
(``position``, ``velocity``, ``acceleration``, each ``(J,)`` in rad, rad/s, rad/s²) and each
:meth:`OnlineMotion.step` calls Ruckig's online ``update`` once:

* Ruckig holds the time-optimal, jerk-limited trajectory from the state it last planned from to the target, at rest
  there (target velocity and acceleration zero), all joints time-synchronised, each within its velocity,
  acceleration and jerk limits (:class:`~studio.motion.limits.JointLimits` × ``speed_scale``).
* When the input changed (a new target from :meth:`~OnlineMotion.set_target`, new limits, a :meth:`~OnlineMotion.reset`)
  Ruckig replans from the current state: the motion bends toward the new target from the current velocity and
  acceleration, so position, velocity and acceleration stay continuous (only jerk may switch). Otherwise it samples
  the trajectory it holds one tick further, which is what replanning from the current state would give (the rest
  of a time-optimal motion is time-optimal) at a tenth of the cost.
* ``out.pass_to_input(inp)`` makes the new state the next tick's current state.

So with an unchanged target the ticks are exactly Ruckig's offline trajectory from the same state sampled at
``k / rate_hz`` (the tests hold the two together within 1e-6 rad), and the sequence is deterministic.

Positions: targets, the start and a reset pose are clipped into ``[lower, upper]``, and Ruckig gets no position
limits of its own. A motion toward a target inside the limits stops at it, and a new target only makes it brake
sooner, so the state stays inside up to floating-point noise (~1e-15 rad, seen when a target lies on a limit);
:meth:`~OnlineMotion.step` returns the position clipped into the limits, so a command never leaves them. The
internal state is not clipped (the motion stays exactly Ruckig's).

A joint whose state is its target up to floating-point residue is first put exactly there (``SETTLE_RAD``: Ruckig
fails on such residues). When Ruckig fails (limits so small that the motion outlasts what it can time, or invalid
input) :meth:`step` raises :class:`MotionError` naming the state and leaves the state as it was: never a silent
wrong position.
Pure compute: no clock, no IO, no threads.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from ruckig import InputParameter, OutputParameter, Result, Ruckig, RuckigError

from studio.motion.errors import MotionError
from studio.motion.limits import JointLimits

AT_TARGET_RAD = 1e-6  # a joint this close to its target (rad), with |velocity| and |acceleration| below it, is there
# A joint within SETTLE_RAD of its target with |velocity| ≤ SETTLE_RAD_S and |acceleration| ≤ SETTLE_RAD_S2 is put
# exactly at its target, at rest, before Ruckig steps: Ruckig 0.x fails ("error in step 2 ... t sync: 0") on such
# floating-point residues (distances of 1e-16..1e-11 rad with velocities of 1e-15..1e-9 rad/s, ~30 % of random
# cases), which a hand holding its pose meets after a replan. The jump is far below a servo step (~4e-3 rad).
SETTLE_RAD, SETTLE_RAD_S, SETTLE_RAD_S2 = 1e-8, 1e-6, 1e-5


@dataclass(frozen=True)
class OnlineConfig:
    """How online motion is stepped."""

    rate_hz: float = 40.0  # ticks a second (the player's 40 Hz: one tick is 25 ms) (0, 1000]
    speed_scale: float = 1.0  # fraction of JointLimits' velocity, acceleration and jerk used (0, 1]

    def __post_init__(self) -> None:
        if not 0 < self.rate_hz <= 1000:
            raise ValueError(f"online motion: rate_hz must be in (0, 1000] Hz, got {self.rate_hz}")
        if not 0 < self.speed_scale <= 1:
            raise ValueError(f"online motion: speed_scale must be in (0, 1], got {self.speed_scale}")

    @property
    def dt(self) -> float:
        """Seconds per tick."""
        return 1.0 / self.rate_hz


class OnlineMotion:
    """A jerk-limited motion toward a changing target (module doc); ``(J,)`` arrays in ``limits``' joint order.

    ``start (J,) rad`` is where it begins, at rest and heading nowhere (target = start); a start outside the joint
    limits is clipped into them, like every pose given to it.
    """

    def __init__(self, limits: JointLimits, start: np.ndarray, cfg: OnlineConfig | None = None):
        self.cfg = cfg or OnlineConfig()
        self.dof = len(limits.lower)
        self._otg = Ruckig(self.dof, self.cfg.dt)
        self._inp, self._out = InputParameter(self.dof), OutputParameter(self.dof)
        self.limits = limits
        self.reset(start)

    @property
    def limits(self) -> JointLimits:
        """The joint limits in use, before ``speed_scale`` (settable at any tick: a ramp-in can start slower and
        switch to the full limits; Ruckig replans from the current state, braking first if it is faster)."""
        return self._limits

    @limits.setter
    def limits(self, limits: JointLimits) -> None:
        if len(limits.lower) != self.dof:
            raise ValueError(f"limits for {len(limits.lower)} joints given to a motion of {self.dof}")
        limits.check()
        self._limits = limits
        s = self.cfg.speed_scale
        self._inp.max_velocity = (np.asarray(limits.velocity, dtype=np.float64) * s).tolist()
        self._inp.max_acceleration = (np.asarray(limits.acceleration, dtype=np.float64) * s).tolist()
        self._inp.max_jerk = (np.asarray(limits.jerk, dtype=np.float64) * s).tolist()

    def slower(self, velocity: float) -> JointLimits:
        """The limits in use with every joint's velocity capped at ``velocity`` rad/s (before ``speed_scale``)."""
        return replace(self._limits, velocity=np.minimum(self._limits.velocity, velocity))

    def _pose(self, theta: np.ndarray, what: str) -> np.ndarray:
        """``theta (J,) rad`` checked and clipped into ``[lower, upper]``; ValueError for a wrong shape or NaN/inf."""
        q = np.asarray(theta, dtype=np.float64)
        if q.shape != (self.dof,):
            raise ValueError(f"the {what} pose must have shape ({self.dof},) rad, got {q.shape}")
        if not np.isfinite(q).all():
            bad = np.flatnonzero(~np.isfinite(q)).tolist()
            raise ValueError(f"the {what} pose has non-finite angles at joints {bad}: {q.tolist()}")
        return np.clip(q, self._limits.lower, self._limits.upper)

    def reset(self, position: np.ndarray) -> None:
        """At rest at ``position (J,) rad`` (clipped into the limits; e.g. the measured pose after a stop), heading
        nowhere (target = position). Ruckig's held trajectory is dropped."""
        q = self._pose(position, "reset").tolist()
        zero = [0.0] * self.dof
        self._inp.current_position, self._inp.current_velocity, self._inp.current_acceleration = q, zero, zero
        self._inp.target_position, self._inp.target_velocity, self._inp.target_acceleration = q, zero, zero
        self._otg.reset()

    def set_target(self, theta: np.ndarray) -> np.ndarray:
        """Head for ``theta (J,) rad`` from the current state (from the next :meth:`step` on); returns the target
        as clipped into ``[lower, upper]``. ValueError for a wrong shape or a non-finite angle (state unchanged)."""
        q = self._pose(theta, "target")
        self._inp.target_position = q.tolist()
        return q.copy()

    def step(self) -> np.ndarray:
        """Advance one tick (``1 / rate_hz`` s); the new position ``(J,) rad`` clipped into ``[lower, upper]``.

        Raises :class:`MotionError` (state unchanged but for the settling below) when Ruckig finds no motion."""
        self._settle()
        try:
            res = self._otg.update(self._inp, self._out)
            why = "" if res in (Result.Working, Result.Finished) else f"result {res}"
        except (RuckigError, RuntimeError, ValueError) as e:  # ValueError: a code the binding lacks, e.g. -101
            why = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
        if why:
            self._otg.reset()  # Ruckig may already hold the failed input as planned: make the next tick replan
            raise MotionError(self._describe(why))
        self._out.pass_to_input(self._inp)
        return np.clip(self.position, self._limits.lower, self._limits.upper)

    def _settle(self) -> None:
        """Joints at their target up to floating-point residue (``SETTLE_*``) put exactly there, at rest."""
        p, v, a, t = self.position, self.velocity, self.acceleration, self.target
        near = (np.abs(p - t) <= SETTLE_RAD) & (np.abs(v) <= SETTLE_RAD_S) & (np.abs(a) <= SETTLE_RAD_S2)
        if near.any() and ((p != t) | (v != 0) | (a != 0))[near].any():
            self._inp.current_position = np.where(near, t, p).tolist()
            self._inp.current_velocity = np.where(near, 0.0, v).tolist()
            self._inp.current_acceleration = np.where(near, 0.0, a).tolist()

    def _describe(self, why: str) -> str:
        worst = int(np.argmax(np.abs(self.target - self.position)))

        def r(a: np.ndarray) -> list[float]:
            return np.round(a, 4).tolist()

        return (
            f"Ruckig could not step the live motion ({why}) from position {r(self.position)} rad, velocity "
            f"{r(self.velocity)} rad/s, acceleration {r(self.acceleration)} rad/s² toward {r(self.target)} rad "
            f"(joint {worst} has the farthest to go, {abs(self.target[worst] - self.position[worst]):.4f} rad) with "
            f"speed_scale {self.cfg.speed_scale}: the velocity/acceleration/jerk limits are too small to reach the "
            "target (raise speed_scale or the limits), then reset() at the measured pose"
        )

    @property
    def position(self) -> np.ndarray:
        """(J,) rad, the commanded position (not clipped; see the module doc)."""
        return np.array(self._inp.current_position, dtype=np.float64)

    @property
    def velocity(self) -> np.ndarray:
        """(J,) rad/s."""
        return np.array(self._inp.current_velocity, dtype=np.float64)

    @property
    def acceleration(self) -> np.ndarray:
        """(J,) rad/s²."""
        return np.array(self._inp.current_acceleration, dtype=np.float64)

    @property
    def target(self) -> np.ndarray:
        """(J,) rad, the clipped target."""
        return np.array(self._inp.target_position, dtype=np.float64)

    @property
    def at_target(self) -> bool:
        """Every joint within ``AT_TARGET_RAD`` of the target and at rest (|velocity|, |acceleration| below it)."""
        return bool(
            np.abs(self.position - self.target).max() <= AT_TARGET_RAD
            and np.abs(self.velocity).max() <= AT_TARGET_RAD
            and np.abs(self.acceleration).max() <= AT_TARGET_RAD
        )
