"""Play a show with a camera watching: every keyframe's real shadow beside its simulated shadow and its target.

The engine of ``play --camera`` and of the Export tab's "play with camera" (issue 25 item 4)::

    with Camera(0) as cam:
        done = play_with_camera(Player(bus, cal), show, cam, targets=show_targets(show, project))
    done.captures[k].losses     # {"captured_vs_target", "simulated_vs_target", "captured_vs_simulated"}

Before anything moves, the camera must give a picture in which the backdrop is found (else :class:`CameraAbsent`,
one line: the show is not played). While the show plays, the player's ``on_sample`` hook (on its 40 Hz thread: a
comparison and a queue put, nothing more) asks for a frame when the show's clock reaches each keyframe's time
(show time = play time minus the ramp-in, from the hand's measured pose to the show's first pose). A grabber thread
waits for the first frame that arrives ``settle_s`` after that moment (skipping ``skip_frames`` more: a frame that
arrives just after it may have been exposed before), and a worker thread finds the backdrop, rectifies the window at
``resolution`` and scores it: the captured mask (1 = shadow) against the keyframe's simulated shadow (the show's
pose as the player sends it, stopped at the calibration's soft limits, rendered on the calibrated rig,
:meth:`Calibration.rig`, with the show's mount roll) as the window
IoU loss, and both against the keyframe's target (when the show or its project has one) as the crop-aligned IoU loss
every result of the project is scored with (DESIGN §4). A camera that fails mid-show is logged and reported per
keyframe; the show goes on and ends as the player decides. The measured pose of each capture is the player's
read-back log interpolated at the frame's time.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from hardware.calibration import Calibration
from hardware.camera import Camera, Frame
from hardware.errors import CameraAbsent, CameraError, HardwareError
from hardware.playback_log import PlaybackResult, StopReason
from hardware.player import Player, SampleHook
from studio.errors import ClosedError, ProgressFn
from studio.motion.show import Show
from studio.project.show_capture_data import LOSSES, KeyframeCapture, ShowCaptureResult, aligned_iou_loss, place
from studio.review.real_vs_sim import window_iou_loss
from studio.sim.backdrop import BackdropLayout
from studio.sim.hand import Hand, load_hand
from studio.sim.shadow import Rig, ShadowRenderer
from studio.targets.backdrop import BackdropNotFound, find_backdrop, rectify, shadow_coverage

__all__ = ["ShowCapture", "ShowCaptureConfig", "check_camera", "play_with_camera", "show_rig"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ShowCaptureConfig:
    """How a show is photographed while it plays."""

    resolution: int = 256  # window pixels per side of the captured and simulated shadows [32, 2048]
    settle_s: float = 0.05  # the frame is taken this long after the clock reaches a keyframe (servo lag), s [0, 5]
    skip_frames: int = 1  # frames skipped after the first newer one (it may be exposed before the moment) [0, 10]
    frame_timeout_s: float = 2.0  # a camera that gives no newer frame within this is stalled, s (0, 60]
    open_timeout_s: float = 10.0  # how long the camera may take to give its first picture, s (0, 120]
    score_during_show: bool = True  # score each picture as it comes (off: after the show; only the grab runs beside it)
    keep_photos: bool = False  # keep each keyframe's photograph (BGR) in its capture

    def __post_init__(self) -> None:
        if not 32 <= self.resolution <= 2048:
            raise ValueError(f"capture resolution must be within 32..2048 pixels, got {self.resolution}")
        ok = 0 <= self.settle_s <= 5 and 0 <= self.skip_frames <= 10 and 0 < self.frame_timeout_s <= 60
        if not (ok and 0 < self.open_timeout_s <= 120):
            raise ValueError(f"a capture setting is out of its range (see ShowCaptureConfig's fields): {self}")


def show_rig(calibration, show: Show) -> Rig:
    """The simulated shadows' rig: the calibration's (measured geometry) with its recorded roll, else the show's."""
    rig = calibration.rig()
    return rig if calibration.roll is not None else rig.with_roll(show.roll)


def check_camera(
    camera: Camera, layout: BackdropLayout | None = None, find: bool = True, timeout_s: float = 10.0
) -> tuple[Frame, np.ndarray]:
    """Open ``camera`` and read one picture (waiting up to ``timeout_s``) in which the backdrop is found → ``(frame,
    H (3, 3) camera px → backdrop m)``; :class:`CameraAbsent` in one line when it cannot (nothing has moved yet).
    ``find=False``: no backdrop search (H is the identity; the caller has clicked corners)."""
    try:
        frame = camera.open().wait_newer(-1, timeout_s)
        return frame, find_backdrop(frame.image, layout) if find else np.eye(3)
    except (CameraError, ClosedError) as e:
        raise CameraAbsent(f"no picture from {camera.name} ({e}): the show was not played") from None
    except BackdropNotFound as e:
        raise CameraAbsent(f"{camera.name} does not see the backdrop ({e}): the show was not played") from None


class ShowCapture:
    """The camera's side of one show being played (module doc). ``rig`` casts the simulated shadows; ``targets``:
    one ``(S, S)`` mask (1 = shadow) or None per keyframe marker of ``show``; ``ramp_s``: the ramp-in before show
    time 0; ``H_backdrop_camera``: the backdrop's homography when it is not searched for (clicked corners), else the
    last one found (used for a frame whose markers are not found)."""

    def __init__(self, camera: Camera, show: Show, rig: Rig, targets: Sequence[np.ndarray | None] | None = None,
                 cfg: ShowCaptureConfig | None = None, layout: BackdropLayout | None = None,
                 H_backdrop_camera: np.ndarray | None = None, find: bool = True, ramp_s: float = 0.0,
                 hand: Hand | None = None, calibration: Calibration | None = None):  # fmt: skip
        self.camera, self.show, self.cfg = camera, show, cfg or ShowCaptureConfig()
        self.layout, self.H, self.find, self.ramp_s = layout or BackdropLayout(), H_backdrop_camera, find, ramp_s
        self.hand = hand or load_hand()
        self.rig = rig.with_resolution(self.cfg.resolution)
        self.key_t = np.array([m.t for m in show.keyframes], dtype=float)  # (K,) s
        K, cols = len(self.key_t), [show.joint_names.index(n) for n in self.hand.joint_names]
        lower, upper = (self.hand.lower, self.hand.upper) if calibration is None else calibration.hand_box(self.hand)
        wanted = show.sample(self.key_t)[:, cols] if K else np.zeros((0, self.hand.dof))  # (K, 21) rad
        self.commanded = np.clip(wanted, lower, upper)  # (K, 21) rad: what the player sends at each keyframe
        R, renderer = self.cfg.resolution, ShadowRenderer(self.hand, self.rig)
        self.simulated = renderer.render(self.commanded) if K else np.zeros((0, R, R), np.uint8)
        self.targets = list(targets) if targets is not None else [None] * K
        if len(self.targets) != K:
            raise ValueError(f"{len(self.targets)} targets for the show's {K} keyframes")
        self.sim_vs_target = [np.nan if t is None else aligned_iou_loss(s, t) for s, t in zip(self.simulated,
                                                                                            self.targets)]  # fmt: skip
        self.camera_error = ""  # the first failure of the camera, "" while it works
        self._requests: queue.Queue = queue.Queue()  # (k, monotonic moment) | None, from the player's hook
        self._frames: queue.Queue = queue.Queue()  # (k, frame | None, error) | None, grabber → worker
        self._done: dict[int, KeyframeCapture] = {}
        self._next, self._t0 = 0, np.inf  # next keyframe to ask for; monotonic time of play time 0 (best seen)
        self._threads = [threading.Thread(target=f, name=f"show-capture-{n}", daemon=True)
                         for n, f in (("grab", self._grab), ("work", self._work))]  # fmt: skip
        self._closed, self._show_over = False, threading.Event()

    # ---------------------------------------------------------------- the player's thread
    def on_sample(self, t: float, commanded: np.ndarray, measured: np.ndarray) -> None:
        """The player's hook at play time ``t`` s: ask for a frame at every keyframe the show's clock has reached."""
        now = time.monotonic()
        self._t0 = min(self._t0, now - t)
        show_t = t - self.ramp_s
        while self._next < len(self.key_t) and show_t >= self.key_t[self._next] - 1e-6:
            self._requests.put((self._next, now))
            self._next += 1

    def hook(self, chained: SampleHook | None = None) -> SampleHook:
        """:meth:`on_sample`, then ``chained`` (another per-tick hook, e.g. a live review) when given."""
        if chained is None:
            return self.on_sample

        def both(t: float, commanded: np.ndarray, measured: np.ndarray) -> None:
            self.on_sample(t, commanded, measured)
            chained(t, commanded, measured)

        return both

    # ---------------------------------------------------------------- the capture threads
    def start(self) -> ShowCapture:
        for thread in self._threads:
            thread.start()
        return self

    def _grab(self) -> None:
        for k, moment in iter(self._requests.get, None):
            timeout = self.cfg.frame_timeout_s if not self.camera_error else min(0.25, self.cfg.frame_timeout_s)
            try:
                frame = self.camera.wait_newer(moment + self.cfg.settle_s, timeout)
                for _ in range(self.cfg.skip_frames):
                    frame = self.camera.wait_newer(frame, timeout)
                self._frames.put((k, frame, ""))
            except (CameraError, ClosedError) as e:
                if not self.camera_error:
                    self.camera_error = str(e)
                    log.warning("the camera failed during the show (the show goes on): %s", e)
                self._frames.put((k, None, f"no picture: {e}"))
        self._frames.put(None)

    def _work(self) -> None:
        if not self.cfg.score_during_show:
            self._show_over.wait()
        for k, frame, error in iter(self._frames.get, None):
            try:
                self._done[k] = self._score(k, frame, error)
            except Exception as e:  # a bug in scoring one picture must not lose the others
                log.exception("keyframe %d's picture could not be scored", k)
                self._done[k] = self._capture(k, error=f"could not be scored ({type(e).__name__}: {e})")

    def _capture(self, k: int, **fields) -> KeyframeCapture:
        losses = dict.fromkeys(LOSSES, np.nan) | {"simulated_vs_target": float(self.sim_vs_target[k])}
        return KeyframeCapture(k, float(self.key_t[k]), self.commanded[k], self.simulated[k], self.targets[k],
                               losses=losses | fields.pop("losses", {}), **fields)  # fmt: skip

    def _score(self, k: int, frame: Frame | None, error: str) -> KeyframeCapture:
        if frame is None:
            return self._capture(k, error=error)
        H = self.H
        if self.find:
            try:
                H = self.H = find_backdrop(frame.image, self.layout)
            except BackdropNotFound as e:
                if H is None:
                    return self._capture(k, error=f"backdrop not found: {e}", frame_t=frame.t)
                log.info("keyframe %d: markers not found, the last backdrop found is used (%s)", k, e)
        coverage = shadow_coverage(rectify(frame.image, H, self.rig.window, self.cfg.resolution))
        captured = (coverage >= 0.5).astype(np.uint8)  # as the capture step's masks
        t = self.targets[k]
        losses = {"captured_vs_simulated": window_iou_loss(captured, self.simulated[k]),
                  "captured_vs_target": np.nan if t is None else aligned_iou_loss(captured, t)}  # fmt: skip
        photo = frame.image.copy() if self.cfg.keep_photos else None
        return self._capture(k, captured=captured, coverage=coverage, losses=losses, frame_t=frame.t,
                             frame_index=frame.index, photo=photo)  # fmt: skip

    # ---------------------------------------------------------------- the end
    def close(self, wait_s: float = 5.0) -> None:
        """Stop asking for frames and let the threads finish what they have (idempotent; never raises)."""
        if not self._closed:
            self._closed = True
            self._requests.put(None)
        self._show_over.set()
        for thread in self._threads:
            if thread.is_alive():
                thread.join(wait_s)

    def finish(self, playback: PlaybackResult) -> list[KeyframeCapture]:
        """After the player returned: a completed show's keyframes not yet asked for (the last, at the show's end)
        are photographed now (the hand holds the last pose); the others are marked as not reached. Waits for the
        pictures asked for, then gives one capture per keyframe with its measured pose and times."""
        if playback.reason == StopReason.COMPLETED and not self._closed:
            now = time.monotonic()
            for k in range(self._next, len(self.key_t)):
                self._requests.put((k, now))
            self._next = len(self.key_t)
        pending = self._requests.qsize() + self._frames.qsize() + 1
        self.close(pending * (self.cfg.frame_timeout_s * (self.cfg.skip_frames + 1) + 1.0))
        why = f"not reached: the show stopped ({playback.reason.value}) before it"
        out = [self._done.get(k) or self._capture(k, error=why) for k in range(len(self.key_t))]
        return place(out, playback, self._t0, self.hand.joint_names)


def _ramp_ticks(player: Player, show: Show) -> int:
    """The ramp-in the player will play, from the hand's pose read now (0 when it cannot be read: the player says)."""
    try:
        start = player.cal.to_rad(np.array([player.bus.read_position(i) for i in player.cal.ids], dtype=float))
    except HardwareError as e:
        log.debug("no ramp-in estimate: %s", e)
        return 0
    return player.trajectory(show.times, show.positions, show.joint_names, start)[1]


def play_with_camera(
    player: Player,
    show: Show,
    camera: Camera,
    cfg: ShowCaptureConfig | None = None,
    targets: Sequence[np.ndarray | None] | None = None,
    layout: BackdropLayout | None = None,
    H_backdrop_camera: np.ndarray | None = None,
    hand: Hand | None = None,
    progress: ProgressFn | None = None,
    cancel: threading.Event | None = None,
) -> ShowCaptureResult:
    """Play ``show`` on ``player`` (its bus and calibration) while ``camera`` photographs each keyframe (module
    doc). ``targets``: one mask or None per keyframe marker (:func:`~studio.project.show_capture_data.show_targets`);
    ``H_backdrop_camera``: clicked corners instead of the markers. Raises :class:`CameraAbsent` before the servos
    move when the camera gives no picture of the backdrop; otherwise never raises for a stop or a camera failure
    (the result says what happened). ``camera`` is opened if needed and left open (the caller closes it)."""
    cfg = cfg or ShowCaptureConfig()
    find = H_backdrop_camera is None
    _, H = check_camera(camera, layout, find, cfg.open_timeout_s)
    rig = show_rig(player.cal, show)
    ramp_s = _ramp_ticks(player, show) / player.cfg.rate_hz
    capture = ShowCapture(camera, show, rig, targets, cfg, layout, H if find else H_backdrop_camera, find, ramp_s,
                          hand, player.cal)  # fmt: skip
    chained = player.on_sample
    player.on_sample = capture.hook(chained)
    capture.start()
    try:
        playback = player.play(show.times, show.positions, show.joint_names, cancel=cancel, progress=progress)
    except BaseException:  # a malformed show or a bug (after the player's safe stop): the threads end, it surfaces
        capture.close(0.5)
        raise
    finally:
        player.on_sample = chained
    captures = capture.finish(playback)
    log.info("captured %d of %d keyframes", sum(c.captured is not None for c in captures), len(captures))
    return ShowCaptureResult(playback, captures, capture.rig, show.title, capture.camera_error)
