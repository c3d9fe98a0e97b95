"""Verb ``live``: the hand casts the shadow an artist is making, as they make it.

::

    shadow-studio live --camera 0 --port /dev/ttyUSB0 [--roll 30] [--record DIR]
    shadow-studio live --camera bear.mp4 --emulator --record runs/live     # a video file as the camera

``--camera`` is a device index, a video file or a frame folder (played at its own rate; ``--loop`` starts it again
at its end, else the session ends once the hand rests on the file's last pose). The engine is
:func:`studio.project.live.run_live` (the notebook's Live panel runs it too). While it runs a status line shows the
updates per second, the latency from a camera frame to its first servo command, the loss of the commanded pose and
why the hand holds, when it does. Ctrl-C, SIGTERM and SIGHUP stop it safely (stop sent, torque as configured); the
e-stop (``shadow-studio estop`` from another terminal) latches it. The playback log is written however it ends
(``--log``, default ``<studio home>/logs/live-<time>.npz``). ``--record DIR`` also writes ``DIR/live.rrd`` (camera,
targets, commanded shadows and poses, commanded vs measured servo angles on ``live_time``) and
``DIR/keyframes.json``, which ``shadow-studio plan`` turns into a show. The JSON summary is printed last.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from functools import partial
from pathlib import Path
from typing import Any

from tqdm import tqdm

from studio.cli.flags import add_config_flags, config_from_args
from studio.cli.progress import add_quiet_flag

LIVE_FIELDS = ("roll_deg", "speed_scale", "ramp_speed_rad_s", "max_seconds", "stall_s", "backdrop")
POSE_FIELDS = ("budget_s", "shortlist", "refine_steps", "w_temporal")
TARGET_FIELDS = ("polarity", "min_share", "max_share")


def cmd_live(args: argparse.Namespace) -> int:
    from hardware.calibration import load_calibration
    from hardware.estop import check_not_latched
    from hardware.playback_log import StopReason, save_playback_log
    from hardware.show_checks import check_mount
    from studio.cli.servo_logs import log_path, save_log
    from studio.cli.servos import session_for
    from studio.cli.signals import exit_code, stop_on_signals
    from studio.imitate.config import LivePoseConfig
    from studio.imitate.still import Imitator
    from studio.project.capture import open_camera_source
    from studio.project.live import run_live
    from studio.project.live_config import LiveConfig
    from studio.review.live_record import LiveRecorder
    from studio.sim.hand import load_hand
    from studio.sim.roll import mount_text
    from studio.targets.live_target import LiveTargetConfig

    if not args.emulator and not args.port:
        raise ValueError("give --port PATH (or --emulator to drive the built-in servo emulator)")
    if str(args.camera).strip() in ("", "virtual"):
        raise ValueError("--camera needs a camera index or a video file or frame folder (the virtual camera "
                         "photographs the hand's own shadow: it is for calibrate-rig and play --camera)")  # fmt: skip
    hand = load_hand()
    cal = load_calibration(args.calibration, hand)
    cfg = config_from_args(args, LiveConfig, hold_torque_on_stop=not args.release_on_stop)
    check_mount(cfg.mount_roll(cal.roll), cal, args.calibration, what="live session")
    pose_cfg = config_from_args(args, LivePoseConfig, prefix="pose-")
    target_cfg = config_from_args(args, LiveTargetConfig, prefix="target-")
    check_not_latched(args.port or "the emulator")  # before the port is opened: nothing to undo
    recorder = LiveRecorder(args.record, hand) if args.record is not None else None  # refuses a bad folder now
    camera = open_camera_source(args.camera)
    camera.loop = args.loop
    log_to = log_path(args.log, "live", ".npz")
    print("loading the self-model and the retrieval index ...", flush=True)
    imitator = Imitator(model_path=args.model)
    status = StatusLine(disable=args.quiet)
    result = None
    try:
        with stop_on_signals("live") as caught, session_for(args, cal, args.emulator, args.release_on_stop) as session:
            if session.emulator is not None:
                print(f"live on the emulator ({session.emulator.port}); Ctrl-C stops safely")
            else:
                print(f"live on {args.port}; Ctrl-C stops safely")
            whose = " (the calibration's)" if cfg.roll_deg is None and cal.roll is not None else ""
            print(f"mount: {mount_text(cfg.mount_roll(cal.roll))}{whose}")
            updates = [status.update] + ([recorder.update] if recorder is not None else [])
            try:
                result = run_live(
                    imitator, session.bus, cal, camera, cfg, pose_cfg, target_cfg,
                    on_update=lambda u: [f(u) for f in updates],
                )  # fmt: skip
            finally:
                status.close()
                if result is not None:
                    save_log(partial(save_playback_log, result.playback), log_to, args.log, "command vs measured")
            session.close()
    finally:
        camera.close()
        imitator.close()
    said = []
    if recorder is not None:
        said = [str(p) for p in recorder.finish(result)]
        print(f"recorded: {', '.join(said)}")
    playback = result.playback
    line = f"{playback.reason.value}: {playback.message}; torque {playback.torque}"
    if playback.ok:
        print(line)
    else:
        print(f"shadow-studio live: stopped: {line}", file=sys.stderr)
    if result.error:
        print(f"shadow-studio live: {result.error}", file=sys.stderr)
    print(json.dumps(result.summary() | ({"files": said} if said else {})))
    if playback.reason == StopReason.INTERRUPTED:
        return exit_code(caught[0] if caught else None)
    return 0 if playback.ok and not result.error else 1


class StatusLine:
    """The terminal's live view: one line, redrawn at most 4 times a second."""

    def __init__(self, disable: bool = False):
        self.bar = tqdm(total=0, bar_format="{desc}", disable=disable)
        self.updates, self._drawn = 0, 0.0

    def update(self, u: Any) -> None:
        self.updates += int(u.theta is not None)
        lat = "-" if not math.isfinite(u.latency_s) else f"{u.latency_s * 1000:.0f} ms"
        loss = "-" if not math.isfinite(u.loss) else f"{u.loss:.3f}"
        self.bar.set_description_str(
            f"live {u.t:6.1f} s  {self.updates} updates  latency {lat}  loss {loss}  {u.status}".rstrip(),
            refresh=False,
        )
        if time.monotonic() - self._drawn >= 0.25:
            self._drawn = time.monotonic()
            self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


def register(sub) -> None:
    from studio.cli.servos import bus_args
    from studio.imitate.config import LivePoseConfig
    from studio.project.live_config import LiveConfig
    from studio.targets.live_target import LiveTargetConfig

    p = sub.add_parser("live", help="the hand follows a camera's silhouette live (Ruckig online at 40 Hz)")
    p.add_argument("--camera", required=True, metavar="SRC", help="camera index, video file or frame folder")
    bus_args(p, port_required=False)
    p.add_argument("--emulator", action="store_true", help="drive the built-in servo emulator instead of --port")
    p.add_argument("--calibration", type=Path, help="calibration YAML (default: assets/calibration.yaml)")
    p.add_argument("--model", type=Path, default=None, help="self-model checkpoint (default: the shipped one)")
    p.add_argument("--loop", action="store_true", help="a video file or frame folder starts again at its end")
    p.add_argument("--record", type=Path, metavar="DIR", help="write DIR/live.rrd and DIR/keyframes.json")
    p.add_argument("--release-on-stop", action="store_true", help="release torque when stopped")
    p.add_argument("--log", type=Path, help="save command vs measured positions to this .npz (default: "
                   "<studio home>/logs/live-<time>.npz)")  # fmt: skip
    add_config_flags(p, LiveConfig, LIVE_FIELDS, aliases={"roll_deg": "roll", "max_seconds": "seconds"})
    add_config_flags(p.add_argument_group("per-frame pose"), LivePoseConfig, POSE_FIELDS, prefix="pose-")
    add_config_flags(p.add_argument_group("camera targets"), LiveTargetConfig, TARGET_FIELDS, prefix="target-")
    add_quiet_flag(p)
    p.set_defaults(func=cmd_live)
