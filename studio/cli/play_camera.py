"""``play --camera SRC``: a camera watches the show; every keyframe's real shadow beside its simulated shadow.

::

    shadow-studio play show.json --port /dev/ttyUSB0 --camera 0 --project my_show.shadow --rrd play.rrd
    shadow-studio play show.json --dry-run --camera virtual --true-rig rig.yaml --captures-out out/captures

``--camera`` is a device index, a video file or frame folder, or ``virtual`` (with ``--dry-run`` and ``--true-rig``:
the emulator's measured angles rendered through the rig as it really is and photographed, as for
``calibrate-rig``). Before the servos move the camera must give a picture in which the backdrop's markers are
found, else the verb refuses in one line. The engine is :func:`studio.project.show_capture.play_with_camera` (the
Export tab's "play with camera" too). After the show it prints, per keyframe, the show time and the losses captured
vs target, simulated vs target (the project's crop-aligned IoU loss; ``-`` where the keyframe has no target: give
``--project`` for a project's show, or a show whose keyframe targets name image files) and captured vs simulated
(window IoU loss), writes ``real_vs_sim.png`` (one row per keyframe: target | captured | simulated | overlay) and
``real_vs_sim.json`` into ``--captures-out`` (with each keyframe's masks and photograph) or beside the log
(``<log name>.real_vs_sim.png``), with ``--rrd FILE`` a Rerun recording of them on ``show_time``, and prints the
JSON summary last. A camera that fails mid-show does not stop the show: the keyframes it missed say so.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from studio.cli.flags import add_config_flags, config_from_args

FIELDS = ("resolution", "settle_s", "skip_frames", "frame_timeout_s", "open_timeout_s", "score_during_show")


def add_camera_flags(p: argparse.ArgumentParser) -> None:
    """``play``'s camera flags."""
    from studio.project.show_capture import ShowCaptureConfig

    g = p.add_argument_group("camera (real versus simulated)")
    flags = (
        ("--camera", str, "SRC", "photograph every keyframe: a camera index, a video file or frame folder, or "
                                 "'virtual' (with --dry-run and --true-rig)"),
        ("--true-rig", Path, "RIG.yaml", "the virtual camera's rig as it really is (YAML)"),
        ("--project", Path, "NAME.shadow", "the project the show was made from: its keyframes' targets"),
        ("--captures-out", Path, "DIR", "folder for real_vs_sim.png/.json and each keyframe's masks and photograph "
                                        "(default: beside the log)"),
        ("--rrd", Path, "FILE", "write a Rerun recording of the captures on show_time to this file"),
    )  # fmt: skip
    for flag, kind, metavar, text in flags:
        g.add_argument(flag, type=kind, metavar=metavar, help=text)
    add_config_flags(g, ShowCaptureConfig, FIELDS, prefix="capture-")


@dataclass
class CameraPlay:
    """What ``play --camera`` needs, read before the servos are opened."""

    args: argparse.Namespace
    cfg: Any  # studio.project.show_capture.ShowCaptureConfig
    targets: list  # one mask or None per keyframe marker of the show

    def play(self, session, player, show, progress) -> Any:
        """Open the camera, play ``show`` on ``player`` with it, close it → ``ShowCaptureResult``."""
        from studio.project.capture import open_camera_source
        from studio.project.show_capture import play_with_camera

        camera = open_camera_source(self.args.camera, session.emulator, player.cal, self.args.true_rig)
        try:
            return play_with_camera(player, show, camera, self.cfg, self.targets, progress=progress)
        finally:
            camera.close()

    def report(self, result: Any, log_to: Path) -> None:
        """The table, the files, the recording; the JSON summary last."""
        from studio.project.show_capture_data import save_captures

        print("\n".join(result.table()))
        if result.camera_error:
            print(f"the camera failed during the show: {result.camera_error}")
        out, prefix = self.args.captures_out, ""
        if out is None:
            out, prefix = log_to.parent, f"{log_to.stem}."
        files = save_captures(result, out, prefix, masks=self.args.captures_out is not None)
        said = [str(files["sheet"]), str(files["summary"])]
        if self.args.rrd is not None:
            from studio.review.real_vs_sim_log import write_capture_recording

            said.append(str(write_capture_recording(self.args.rrd, result.captures, result.playback)))
        print(f"real vs simulated: {', '.join(said)}")
        print(json.dumps(result.summary() | {"files": said}))


def prepare_camera(args: argparse.Namespace, show: Any) -> CameraPlay | None:
    """None without ``--camera``; else its flags checked and the show's targets read (before any port opens)."""
    if args.camera is None:
        extra = [f for f in ("true_rig", "project", "captures_out", "rrd") if getattr(args, f) is not None]
        if extra:
            flag = "--" + extra[0].replace("_", "-")
            raise ValueError(f"{flag} goes with --camera: give the camera that watches the show")
        return None
    from studio.project.show_capture import ShowCaptureConfig
    from studio.project.show_capture_data import show_targets

    virtual = args.camera.strip() == "virtual"
    if args.camera.strip() == "":
        raise ValueError("--camera needs a camera index, a video file or frame folder, or 'virtual'")
    if virtual and (not args.dry_run or args.true_rig is None):
        raise ValueError("--camera virtual photographs the emulator's hand through the rig as it really is: add "
                         "--dry-run and --true-rig RIG.yaml")  # fmt: skip
    if not virtual and args.true_rig is not None:
        raise ValueError("--true-rig describes the virtual camera's world: use it with --camera virtual")
    project = None
    if args.project is not None:
        from studio.project.project import Project

        project = Project.open(args.project)
    cfg = config_from_args(args, ShowCaptureConfig, prefix="capture-", keep_photos=args.captures_out is not None)
    targets = show_targets(show, project, args.show.parent)
    return CameraPlay(args, cfg, targets)
