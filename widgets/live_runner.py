"""What the Live panel's Start runs (:mod:`widgets.live`): one session at a time, in a thread of its own.

:meth:`LiveRunner.start` starts the thread, which says what it does on the panel's messages as it goes: the camera
is tried first (a bad source is one line, before any servo is opened), then the e-stop's latch, the self-model and
its retrieval index (loaded on the first Start and kept for the next; the index is built once per machine, its
progress said at most four times a second), the servos (the Jog panel's connection when it is connected to the same
servos, else a :class:`~hardware.session.ServoSession` of the runner's own), then
:func:`studio.project.live.run_live`, whose planner thread offers its updates to the panel's
:class:`~widgets.live_view.LiveView` (and, when recording, to a :class:`~studio.review.live_record.LiveRecorder`).
:meth:`LiveRunner.stop`, from any thread, ends the session at the next tick; pressed before the engine's session
exists, it stops that session as soon as there is one, before the hand moves.

It ends fail-safe however it ends: the camera closes first, then the runner's own servos (stopped, torque held
unless the session releases it, the close never raising); the Jog panel's servos are sent a stop and stay connected.
Every end (done, stopped, refused by the e-stop's latch, a bad camera, port or file, a bug) is one line saying why
and how the servos were left, never a traceback. That line lands under the lock Stop's "stopping…" takes too, so it
is always the last; the panel's ``ended`` hook then gives its buttons back. The engine is imported on the first
Start (it loads torch).
"""

from __future__ import annotations

import logging
import tempfile
import threading
import time
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from hardware.calibration import Calibration
from hardware.errors import EStopLatched
from hardware.estop import check_not_latched
from hardware.serial_bus import BusConfig
from hardware.session import CloseReport, ServoSession
from studio.errors import Cancelled, Progress, StudioError
from studio.project.capture import open_camera_source
from widgets.images import Messages
from widgets.live_view import LiveView, check_roll, ended_line
from widgets.words import stage

if TYPE_CHECKING:
    from studio.imitate.config import LivePoseConfig
    from studio.imitate.retrieval import RetrievalConfig
    from studio.imitate.still import Imitator
    from studio.project.live import LiveResult, LiveSession
    from studio.project.live_config import LiveConfig
    from studio.targets.live_target import LiveTargetConfig

log = logging.getLogger(__name__)


class LiveSettings(Protocol):
    """What a session reads, at each Start, from the panel's config (:class:`widgets.live.LivePanelConfig`)."""

    live: LiveConfig | None  # the session (None: the defaults); its roll_deg is the Ask's
    pose: LivePoseConfig | None  # how a frame becomes a pose (None: the defaults)
    target: LiveTargetConfig | None  # how a frame becomes a target (None: the defaults)
    retrieval: RetrievalConfig | None  # the retrieval index (None: the searches' own)
    timeout_s: float | None  # s to wait for one servo's answer, on servos the runner opens (None: the bus's default)


@dataclass(frozen=True)
class Ask:
    """What the artist asked for when they pressed Start."""

    source: str  # the camera
    loop: bool  # a file or folder starts again at its end
    port: str | None  # None: the emulator
    roll_deg: float  # the mount's roll
    record: bool  # write live.rrd and keyframes.json too
    folder: Path  # where the session's folder goes


class LiveRunner:
    """Runs the Live panel's sessions, one at a time, each in a thread of its own (module doc).

    ``calibration`` gives the studio's calibration (saying, when its file is bad, that the shipped one is used);
    ``jog`` the Jog panel's servo session, if there is one; ``ended`` is called from the session's thread once a
    session has ended, after its line, with the lock held."""

    def __init__(self, messages: Messages, view: LiveView, cfg: LiveSettings, calibration: Callable[[], Calibration],
                 jog: Callable[[], ServoSession | None], ended: Callable[[], None]):  # fmt: skip
        self.messages, self.view, self.cfg = messages, view, cfg
        self.calibration, self.jog, self.ended = calibration, jog, ended
        self.imitator: Imitator | None = None  # loaded on the first Start, kept for the next
        self.result: LiveResult | None = None  # the last session's
        self.files: list[Path] = []  # what the last session wrote (its log first)
        self.servos: ServoSession | None = None  # the servos in use while a session runs
        self.live_session: LiveSession | None = None  # the engine's session while the hand moves
        self.last_close: CloseReport | None = None  # how the servos this runner opened were left
        self._borrowed = False  # the servos in use are the Jog panel's (not closed by this runner)
        self._lock = threading.Lock()  # Stop's "stopping…" never lands after the line that ends a session
        self._active = False
        self._cancel = threading.Event()
        self._stop_pressed = False
        self._said = 0.0  # monotonic time of the last progress line

    @property
    def running(self) -> bool:
        """Whether a session (or its start) runs now."""
        return self._active

    def start(self, ask: Ask) -> threading.Thread:
        """Start a session for ``ask`` (the caller has checked that none runs); its thread, started."""
        self._cancel, self._stop_pressed, self._borrowed = threading.Event(), False, False
        self.result, self.files, self._active = None, [], True
        thread = threading.Thread(target=self._run, args=(ask, self._cancel), name="live-session", daemon=True)
        thread.start()
        return thread

    def stop(self) -> bool:
        """End the session at the next tick (servos stopped), without waiting for it; whether one ran."""
        with self._lock:
            if not self._active:
                return False
            self._stop_pressed = True
            self.messages.say("stopping: the hand stops where it is…")
            self._cancel.set()
            if (s := self.live_session) is not None:
                s.stop()
        return True

    def close(self) -> None:
        """Let the self-model go (call once no session runs)."""
        if self.imitator is not None:
            self.imitator.close()
            self.imitator = None

    # ---------------------------------------------------------------- the session's thread
    def _run(self, ask: Ask, cancel: threading.Event) -> None:
        """Camera, latch, self-model, servos, session, outcome: every end a line in the panel."""
        line, error, self.last_close = "", False, None
        try:
            with ExitStack() as stack:  # the camera closes first, then the runner's own servos (stopped)
                line, error = self._session(ask, cancel, stack)
            if self.last_close is not None and not self.last_close.stopped:
                line, error = f"{line}; {self.last_close.message}", True
        except Cancelled:
            line = f"stopped before the hand moved; {self._left()}"
        except EStopLatched as e:
            line, error = f"cannot start: {e} (press reset e-stop); {self._left()}", True
        except (StudioError, ValueError, OSError) as e:  # the camera, the port, the calibration, a file
            line, error = f"could not run live: {e}; {self._left()}", True
        except Exception as e:  # a bug: the servos stopped, a line in the panel, never a traceback
            log.debug("live session failed", exc_info=True)
            line, error = f"live failed unexpectedly ({type(e).__name__}: {e}); {self._left()}", True
        finally:
            self.live_session, self.servos = None, None
            with self._lock:
                self.messages.say(line, error=error)
                self.ended()
                self._active = False

    def _session(self, ask: Ask, cancel: threading.Event, stack: ExitStack) -> tuple[str, bool]:
        from studio.project.live import run_live
        from studio.project.live_config import LiveConfig
        from studio.review.live_record import LiveRecorder

        with open_camera_source(ask.source) as probe:  # a camera that gives no picture fails here
            self.view.show_frame(probe.latest().image)
        cal = self.calibration()
        check_roll(ask.roll_deg, cal)
        check_not_latched("the servos")
        imitator = self._imitator(cancel)
        cfg = replace(self.cfg.live or LiveConfig(), roll_deg=ask.roll_deg)
        session = self.servos = self._open_servos(stack, ask.port, cal, cfg.hold_torque_on_stop)
        ask.folder.mkdir(parents=True, exist_ok=True)
        folder = Path(tempfile.mkdtemp(prefix=time.strftime("%Y%m%d-%H%M%S-"), dir=ask.folder))
        recorder = LiveRecorder(folder, imitator.hand) if ask.record else None
        camera = open_camera_source(ask.source)
        camera.loop = ask.loop
        stack.callback(camera.close)
        if cancel.is_set():
            raise Cancelled("stopped")
        self.messages.say("warming up (the first frame's pose is compiled once)…")

        def on_update(u: Any) -> None:  # the planner's thread: keep it quick
            self.view.offer(u)
            if recorder is not None:
                recorder.update(u)

        result, log_path = None, folder / "playback.npz"
        self.view.begin()
        try:
            result = run_live(imitator, session.bus, cal, camera, cfg, self.cfg.pose, self.cfg.target,
                              on_update=on_update, cancel=cancel, log_path=log_path,
                              session_ready=lambda s: self._ready(s, ask, cancel))  # fmt: skip
        finally:
            self.view.end()
            self.live_session = None
            files = recorder.finish(result) if recorder is not None else []
        self.result, self.files = result, [log_path, *files]
        left = self._left(stack)
        error = bool(result.error) or not (result.playback.ok or self._stop_pressed)
        return ended_line(result, cfg, self._stop_pressed, left, folder, self.files), error

    def _ready(self, session: LiveSession, ask: Ask, cancel: threading.Event) -> None:
        """The engine's session, before the hand moves: Stop can reach it from now on."""
        with self._lock:
            self.live_session = session
            if cancel.is_set():
                session.stop()
                return
            where = "the emulator" if ask.port is None else ask.port
            self.messages.say(f"live on {where}: the hand follows the camera (Stop ends it, E-STOP halts it at once)")

    def _imitator(self, cancel: threading.Event) -> Imitator:
        """The self-model and its retrieval index, loaded once (built once per machine, with progress)."""
        if self.imitator is None:
            self.messages.say("loading the self-model…")
            from studio.imitate.still import Imitator

            self.imitator = Imitator(retrieval=self.cfg.retrieval)
        self.messages.say("loading the retrieval index…")
        if self.imitator.retrieval_index(progress=self._progress, cancel=cancel) is None:
            raise Cancelled("the retrieval index's build was stopped")
        return self.imitator

    def _progress(self, p: Progress) -> None:
        now = time.monotonic()
        if now - self._said >= 0.25:
            self._said = now
            share = f": {p.fraction:.0%}" if p.total > 0 else "…"
            self.messages.say(f"{stage(p.stage, p.total, p.item)}{share}")

    def _open_servos(self, stack: ExitStack, port: str | None, cal: Calibration, hold: bool) -> ServoSession:
        """The Jog panel's session when it is connected to the chosen servos, else one of the runner's own, closed
        (servos stopped, torque held unless the session releases it) when ``stack`` closes."""
        jog = self.jog()
        self._borrowed = jog is not None and jog.is_open and (jog.emulator is not None if port is None else
                                                              jog.port == port)  # fmt: skip
        if self._borrowed:
            return jog
        self.messages.say(f"opening {'the servo emulator' if port is None else port}…")
        config = BusConfig(port or "", timeout_s=self.cfg.timeout_s)
        session = ServoSession(port, calibration=cal, config=config, release_on_close=not hold).open()
        stack.callback(lambda: setattr(self, "last_close", session.close()))  # close() never raises
        return session

    def _left(self, stack: ExitStack | None = None) -> str:
        """How the servos are left: the runner's own closed now (``stack``) or already, the Jog panel's sent a stop."""
        session = self.servos
        if session is None:
            return "the servos were not opened"
        if self._borrowed:
            try:
                session.bus.stop()
                return "servos stopped (the Jog panel stays connected)"
            except Exception as e:  # the Jog panel's bus failed: it says so itself on its next move
                return f"the stop did not reach the servos ({e}): cut their power if they still move"
        if stack is not None:
            stack.close()
        return session.close().message  # closed already: how it was left
