"""What the Jog panel's buttons do (mixed into :class:`widgets.jog.JogPanel`): read the studio's calibration again
(at connect), move a joint, read back, torque, home, the selected keyframe's pose, the e-stop and its reset, and the
periodic read-back (a thread that only sets label values, ≤ 10 Hz). Each goes through ``_do`` (every error a
message, anything unexpected a stop: DESIGN §5.13) on the connected :class:`hardware.jog.Jog`."""

from __future__ import annotations

import logging
import math
import threading

import numpy as np

from hardware.errors import BusError, EStopLatched
from hardware.jog import JogMove
from hardware.show_checks import beyond_names, beyond_soft_limits
from studio.errors import StudioError
from widgets.calibration_file import studio_calibration

log = logging.getLogger(__name__)


class JogActions:
    """Actions of ``JogPanel`` (it provides ``state``, ``hand``, ``cal``, ``_given``, ``sliders``, ``_quiet``,
    ``jog``, ``bus``, ``_say``, ``_set_enabled``, ``_show_target``, ``_show_measured``, ``_lost``, ``_refresh_stop``,
    ``_refresh_thread``, ``keyframe_button`` and ``torque_on``)."""

    def _read_calibration(self, what: str) -> bool:
        """Read the studio's calibration again (not a given one) and fit the sliders to its soft limits; whether it
        could be read (a file that cannot be is said, "could not ``what``", and nothing changes)."""
        if self._given is not None:
            return True
        try:
            cal = studio_calibration(self.state, self.hand, strict=True)
        except StudioError as e:
            self._say(f"could not {what}: {e}", error=True)
            return False
        if cal != self.cal:
            self.cal = cal
            self._quiet = True
            try:
                for s, j in zip(self.sliders, cal.joints, strict=True):
                    lo, hi = math.degrees(j.lower), math.degrees(j.upper)
                    s.min, s.max = min(s.min, lo), max(s.max, hi)  # widen first: min never passes max
                    s.min, s.max = lo, hi
            finally:
                self._quiet = False
        return True

    def _do(self, what: str, action):
        """Run ``action()`` on the connected jog; every error becomes a message (DESIGN §5.13)."""
        if self.jog is None:
            self._say(f"cannot {what}: not connected (press connect)", error=True)
            return None
        try:
            return action()
        except EStopLatched:
            self._set_enabled(True, latched=True)
            self._say(f"cannot {what}: the E-STOP is latched; nothing moves until you press reset", error=True)
        except BusError as e:
            self._lost(e)
        except (StudioError, ValueError) as e:
            self._say(f"cannot {what}: {e}", error=True)
        except Exception as e:  # a bug: stop the servos, say so, never a traceback in the notebook
            log.debug("jog panel: %s failed", what, exc_info=True)
            try:
                self.bus.stop()
            except Exception:
                pass
            self._say(f"{what} failed unexpectedly ({type(e).__name__}: {e}); the servos were sent a stop", True)
        return None

    def _moved(self, m: JogMove) -> None:
        self._show_target()
        self._say(self.jog._say(m))

    def move(self, joint: str | int, deg: float) -> JogMove | None:
        """Move one joint to ``deg`` degrees (clipped to its soft limits, said so); the move as sent."""

        def go() -> JogMove:
            self.jog.select(joint)
            m = self.jog.go(math.radians(deg))
            self._moved(m)
            return m

        return self._do(f"move {joint}", go)

    def read(self) -> np.ndarray | None:
        """Measured angles ``(J,) rad`` (NaN: no answer), shown beside the sliders."""

        def read() -> np.ndarray:
            q = self.jog.read_array(strict=False)
            self._show_measured(q)
            silent = [i for i, x in zip(self.cal.ids, q) if not math.isfinite(x)]
            self._say(f"read back; servos {silent} did not answer" if silent else "read back every servo")
            return q

        return self._do("read back", read)

    def torque(self, on: bool) -> None:
        """Torque on (holding the measured pose) or off (limp) for every servo."""

        def torque() -> None:
            self.jog.torque(on)
            self.torque_on = on
            self._show_target()
            self._say("torque on: holding the measured pose" if on else "torque off: the hand is limp")

        self._do("switch torque " + ("on" if on else "off"), torque)

    def home(self) -> JogMove | None:
        """Every joint to the rest pose, ramped at jog speed."""
        return self._do("go home", lambda: self._moved(self.jog.home()))

    def selected_keyframe(self) -> int | None:
        """The keyframe in view: the selection's, else the keyframe of the selected frame."""
        sel, project = self.state.selection, self.state.project
        if sel.keyframe is not None:
            return sel.keyframe
        if not project.keyframes or not project.frames:
            return None
        return project.keyframes[int(project.assignment()[sel.frame])].id

    def go_keyframe(self) -> JogMove | None:
        """The selected keyframe's pose (its result), ramped at jog speed (clipped to the soft limits)."""
        k = self.selected_keyframe()
        result = None if k is None else self.state.project.results.get(k)
        if result is None:
            self._say("no keyframe selected" if k is None else f"keyframe {k} has no pose yet: optimise it first",
                      error=True)  # fmt: skip
            return None

        def go() -> JogMove:
            theta = result.theta(self.cal.joint_names)
            m = self.jog.go_pose(theta)
            self._show_target()
            stale = " (its result is stale)" if self.state.project.is_stale(k) else ""
            beyond = beyond_soft_limits(theta[None], self.cal.joint_names, self.cal)
            clipped = f", stopped at the soft limits ({beyond_names(beyond)})" if beyond else ""
            self._say(f"keyframe {k}'s pose{stale} in {m.duration_s:.2f} s{clipped}")
            return m

        return self._do(f"go to keyframe {k}", go)

    def estop(self) -> bool:
        """Latch the e-stop: every servo halts now; nothing moves until :meth:`reset`. Returns whether the halt
        reached the bus."""
        if self.jog is None:
            self._say("not connected: nothing to stop", error=True)
            return False
        reached = self.jog.estop()  # never raises
        self._set_enabled(True, latched=True)
        if reached:
            self._say("E-STOP: servos halted and latched; press reset to move again", error=True)
        else:
            self._say("E-STOP latched, but the halt did not reach the bus: cut the servos' power", error=True)
        return reached

    def reset(self) -> None:
        """Clear the e-stop; the sliders follow where it left the servos."""

        def reset() -> None:
            self.jog.reset()
            self._set_enabled(True)
            self._show_target()
            self._say("e-stop reset: the sliders move the servos again")

        self._do("reset the e-stop", reset)

    def _auto_refresh(self, on: bool) -> None:
        self._refresh_stop.set()
        t, self._refresh_thread = self._refresh_thread, None
        if t is not None:
            t.join(2.0)
        if on and self.jog is not None:
            self._refresh_stop = stop = threading.Event()
            self._refresh_thread = threading.Thread(target=self._refresh, args=(stop,), name="jog-refresh",
                                                    daemon=True)  # fmt: skip
            self._refresh_thread.start()

    def _refresh(self, stop: threading.Event) -> None:
        """Read back every ``1/refresh_hz`` s until stopped; only sets label values (DESIGN §6)."""
        period = 1.0 / min(max(self.cfg.refresh_hz, 0.1), 10.0)
        while not stop.wait(period):
            jog = self.jog
            if jog is None:
                return
            try:
                self._show_measured(jog.read_array(strict=False))
            except BusError as e:
                if not stop.is_set():
                    self._lost(e)
                return
            except Exception as e:  # keep reading; say what went wrong
                self._say(f"read back failed: {e}", error=True)
