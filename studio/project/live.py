"""Live: the hand casts the shadow an artist is making, as they make it (``shadow-studio live``, the Live panel).

One engine for both faces. Three threads:

- the **camera** (:class:`hardware.camera.Camera`) keeps the newest frame;
- the **planner** (here) takes each new frame through the target pipeline
  (:class:`~studio.targets.live_target.LiveTargets`: the backdrop's homography when its markers are in the picture,
  binarisation), finds a pose within the per-frame budget (:class:`~studio.imitate.live_pose.LivePoser`: retrieval,
  a short refinement warm-started from the previous pose, the temporal term), keeps only collision-free targets
  with a collision-free path, and hands them to the motion;
- the **player** (:meth:`hardware.player.Player.stream`, the caller's thread) runs Ruckig online from the hand's
  measured pose to the newest target at 40 Hz on the bus (:class:`~studio.project.live_ticks.LiveTicks`), with the
  safety of playback: ramp-in from the measured pose, the e-stop latch, stop conditions, the torque policy.

When the camera stalls or the silhouette vanishes, the hand holds its last target and every update says why. A
video file that ends ends the session once the hand rests on its last target; ``cancel`` or :meth:`LiveSession.stop`
end it at once (the player's safe stop). Whatever happens, the playback log is written to ``log_path`` (when given)
before :func:`run_live` returns or raises.

Each planner step reports a :class:`LiveUpdate` through ``on_update`` (the CLI's status line, the panel, the Rerun
recording of ``--record``): the camera frame, the target, the commanded pose and its shadow as the mount casts it,
the loss, the latency measured so far, and the status.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from hardware.camera import Camera, CameraEnded, CameraStalled
from hardware.playback_log import PlaybackResult, save_playback_log
from hardware.player import Player, PlayerConfig
from studio.imitate.config import LivePoseConfig
from studio.imitate.live_pose import LivePose, LivePoser
from studio.motion.limits import JointLimits
from studio.project.live_config import LiveConfig
from studio.project.live_ticks import LiveTicks
from studio.sim.roll import roll_deg
from studio.targets.backdrop import BackdropNotFound, find_backdrop
from studio.targets.live_target import LiveTargetConfig, LiveTargets

if TYPE_CHECKING:
    from hardware.bus import ServoBus
    from hardware.calibration import Calibration
    from studio.imitate.still import Imitator

log = logging.getLogger(__name__)
UpdateFn = Callable[["LiveUpdate"], None]


@dataclass
class LiveUpdate:
    """What one planner step saw and did (plain data; images are read-only views, copy to keep them)."""

    t: float  # s since the session started (the frame's arrival)
    frame_index: int  # the camera frame's index
    image: np.ndarray  # (H, W, 3) uint8 BGR, the camera frame
    target: np.ndarray | None  # (R, R) uint8, 1 = shadow; None: no silhouette in the frame
    theta: np.ndarray | None  # (21,) rad, the hand's order: the pose commanded for this frame (None: holding)
    shadow: np.ndarray | None  # (R, R) uint8, that pose's shadow as the rolled mount casts it
    loss: float  # the shadow's loss against the target (NaN when holding)
    first_loss: float  # the retrieval's best candidate's loss before refinement (NaN when holding)
    pose_s: float  # s the pose took
    latency_s: float  # s, median latency from a frame to its first servo command so far (NaN before the first)
    status: str  # "" while following; else why the hand holds ("holding: the camera stalled ...")


@dataclass
class LiveResult:
    """How a session went."""

    playback: PlaybackResult  # the player's result (why it ended, the torque state, commanded and measured)
    updates: int  # targets handed to the motion
    frames: int  # camera frames the planner took
    holds: dict[str, int]  # status → planner steps that held for it
    latencies_s: np.ndarray  # (U,) s, frame arrival → its first servo command, per sent target
    losses: np.ndarray  # (U,) each commanded pose's loss against its frame's target
    first_losses: np.ndarray  # (U,) the retrieval's best candidate's loss, same frames
    poses: np.ndarray  # (U, 21) rad, the hand's order, the commanded target poses
    times: np.ndarray  # (U,) s since the start, the frames' arrival
    seconds: float  # the session's length
    backdrop: bool  # the camera frames were rectified through the backdrop's homography
    error: str = ""  # what the planner or camera met that ended the session early ("" when none)
    roll: float = 0.0  # rad, the mount roll the poses were chosen for (DESIGN §1)
    extra: dict = field(default_factory=dict)

    @property
    def updates_per_s(self) -> float:
        return self.updates / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> dict:
        """The figures a person reads (JSON-ready)."""
        lat = self.latencies_s * 1000
        pct = (lambda q: round(float(np.percentile(lat, q)), 1)) if len(lat) else (lambda q: None)
        return {
            "stopped": self.playback.reason.value,
            "message": self.playback.message,
            "torque": self.playback.torque,
            "seconds": round(self.seconds, 2),
            "frames": self.frames,
            "updates": self.updates,
            "updates_per_s": round(self.updates_per_s, 2),
            "latency_p50_ms": pct(50),
            "latency_p99_ms": pct(99),
            "mean_loss": round(float(self.losses.mean()), 4) if len(self.losses) else None,
            "holds": dict(self.holds),
            "backdrop": self.backdrop,
            "roll_deg": roll_deg(self.roll),
            "error": self.error,
        }


class LiveSession:
    """The planner's side of a session; :func:`run_live` builds and runs one (module doc)."""

    def __init__(self, imitator: Imitator, calibration: Calibration, camera: Camera, cfg: LiveConfig,
                 pose_cfg: LivePoseConfig, target_cfg: LiveTargetConfig, on_update: UpdateFn | None):  # fmt: skip
        self.im, self.cal, self.camera, self.cfg = imitator, calibration, camera, cfg
        hand = imitator.hand
        missing = sorted(set(calibration.joint_names) ^ set(hand.joint_names))
        if missing:
            raise ValueError(f"the calibration's joints do not match the hand's: {missing}")
        order = [hand.joint_names.index(n) for n in calibration.joint_names]
        lim = JointLimits.from_hand(hand)
        lim = JointLimits(
            np.maximum(lim.lower[order], calibration.lower), np.minimum(lim.upper[order], calibration.upper),
            lim.velocity[order], lim.acceleration[order], lim.jerk[order],
        )  # fmt: skip
        self.ticks = LiveTicks(lim, order, PlayerConfig().rate_hz, cfg.speed_scale, cfg.ramp_speed_rad_s)
        self.roll = cfg.mount_roll(calibration.roll)
        box = calibration.hand_box(hand)  # the servos' soft limits, in the hand's order
        self.poser = LivePoser(imitator.retrieval_index(), imitator.refiner, pose_cfg, roll=self.roll, box=box)
        self.target_cfg = target_cfg
        self.on_update = on_update
        self.stopping = threading.Event()
        self.error = ""
        self.frames, self.holds = 0, {}
        self.kept: list[tuple[float, np.ndarray, float, float]] = []  # (t, θ, loss, first loss) per update
        self.backdrop = False
        self.t0 = time.monotonic()

    def warm_up(self) -> None:
        """Compile the kernels on a dummy target, so the first frame is answered within its budget."""
        r = self.im.resolution
        blob = np.zeros((r, r), np.uint8)
        blob[r // 4 : 3 * r // 4, r // 3 : 2 * r // 3] = 1
        self.poser.pose(blob)
        self.poser.reset()

    def targets(self) -> LiveTargets:
        """The target pipeline, with the backdrop's homography when the first frame shows its markers."""
        H = None
        if self.cfg.backdrop == "auto":
            try:
                H = find_backdrop(np.asarray(self.camera.latest().image))
            except BackdropNotFound:
                log.info("no backdrop markers in the camera's picture: the whole frame is the target")
        self.backdrop = H is not None
        return LiveTargets(replace(self.target_cfg, resolution=self.im.resolution), H, self.im.renderer.rig.window)

    def stop(self) -> None:
        """End the session now (the hand holds where it was commanded)."""
        self.stopping.set()
        self.ticks.stop()

    def plan(self) -> None:
        """The planner loop (its own thread): frames → targets → poses → the motion, until stopped or the file ends."""
        try:
            self._plan()
        except Exception as e:  # the session must end safely; the caller reports it
            log.exception("the live planner failed")
            self.error = f"the planner failed: {type(e).__name__}: {e}"
            self.ticks.stop()

    def _hold(self, frame, status: str, target=None) -> None:
        self.holds[status] = self.holds.get(status, 0) + 1
        self._say(frame, target, None, status)

    def _plan(self) -> None:
        targets = self.targets()
        while not self.ticks.started.wait(0.05):  # the player reads the measured pose first
            if self.stopping.is_set():
                return
        last = -1
        while not self.stopping.is_set():
            if self.cfg.max_seconds and time.monotonic() - self.t0 >= self.cfg.max_seconds:
                self.ticks.finish()
                return
            try:
                frame = self.camera.wait_newer(last, self.cfg.stall_s)
            except CameraStalled as e:
                self._hold(None, f"holding: {e}")
                continue
            except CameraEnded:
                self.ticks.finish()
                return
            last = frame.index
            self.frames += 1
            got = targets(np.asarray(frame.image))
            if got.mask is None:
                self._hold(frame, f"holding: {got.reason}")
                continue
            pose = self.poser.pose(got.mask, from_theta=self.ticks.commanded_hand())
            if not pose.path_free:
                self._hold(frame, "holding: no collision-free way to the new pose", got.mask)
                continue
            self.ticks.aim(pose.theta, frame.t, frame.index)
            self.kept.append((frame.t - self.t0, pose.theta, pose.loss, pose.first_loss))
            self._say(frame, got.mask, pose, "")

    def _say(self, frame, target, pose: LivePose | None, status: str) -> None:
        if status:
            log.debug("%s", status)
        if self.on_update is None:
            return
        lat = self.ticks.latencies
        shadow = None
        if pose is not None:
            shadow = self.poser.refiner.renderer.render_one(pose.theta)  # as the rolled mount casts it
        image = np.zeros((1, 1, 3), np.uint8) if frame is None else np.asarray(frame.image)
        self.on_update(LiveUpdate(
            t=(time.monotonic() if frame is None else frame.t) - self.t0,
            frame_index=-1 if frame is None else frame.index, image=image, target=target,
            theta=None if pose is None else pose.theta, shadow=shadow,
            loss=np.nan if pose is None else pose.loss, first_loss=np.nan if pose is None else pose.first_loss,
            pose_s=np.nan if pose is None else pose.seconds,
            latency_s=float(np.median(lat)) if len(lat) else np.nan, status=status,
        ))  # fmt: skip

    def result(self, playback: PlaybackResult) -> LiveResult:
        kept = self.kept
        sent = {a.frame_index: a.sent_t - a.frame_t for a in self.ticks.aims if a.sent_t is not None}
        return LiveResult(
            playback=playback,
            updates=len(kept),
            frames=self.frames,
            holds=self.holds,
            latencies_s=np.array(list(sent.values()), dtype=float),
            losses=np.array([k[2] for k in kept], dtype=float),
            first_losses=np.array([k[3] for k in kept], dtype=float),
            poses=np.array([k[1] for k in kept], dtype=float).reshape(len(kept), -1),
            times=np.array([k[0] for k in kept], dtype=float),
            seconds=time.monotonic() - self.t0,
            backdrop=self.backdrop,
            error=self.error,
            roll=self.roll,
        )


def run_live(
    imitator: Imitator,
    bus: ServoBus,
    calibration: Calibration,
    camera: Camera,
    cfg: LiveConfig | None = None,
    pose_cfg: LivePoseConfig | None = None,
    target_cfg: LiveTargetConfig | None = None,
    on_update: Callable[[LiveUpdate], None] | None = None,
    on_sample: Callable | None = None,
    cancel: threading.Event | None = None,
    log_path: Path | None = None,
    session_ready: Callable[[LiveSession], None] | None = None,
) -> LiveResult:
    """Run a live session (module doc) on ``bus`` through ``calibration`` with ``camera`` (opened here if it is
    not open; the caller closes it) and ``imitator``'s self-model, index and renderer. ``session_ready`` gets the
    :class:`LiveSession` before the hand moves (the panel's Stop button); ``on_sample(t, commanded, measured)`` is
    the player's hook. Never raises for a stop; a planner failure ends the session early (``LiveResult.error``)."""
    cfg = cfg or LiveConfig()
    session = LiveSession(imitator, calibration, camera, cfg, pose_cfg or LivePoseConfig(),
                          target_cfg or LiveTargetConfig(), on_update)  # fmt: skip
    session.warm_up()
    camera.open()
    camera.latest()  # a camera that gives no picture fails here, before the servos move
    if session_ready is not None:
        session_ready(session)
    player = Player(bus, calibration, PlayerConfig(hold_torque_on_stop=cfg.hold_torque_on_stop), on_sample=on_sample)
    planner = threading.Thread(target=session.plan, name="live-planner", daemon=True)
    session.t0 = time.monotonic()
    planner.start()
    playback = None
    try:
        playback = player.stream(session.ticks, cancel=cancel)
    finally:
        session.stop()
        planner.join(timeout=5.0)
        playback = playback or player.last_result
        if log_path is not None and playback is not None:
            save_playback_log(playback, log_path)
    return session.result(playback)
