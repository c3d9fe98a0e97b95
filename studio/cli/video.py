"""``shadow-studio keyframes SRC``: a video's keyframes, as the sequence optimiser will see them.

Loads the video or frame folder (sampled at ``--hz``), computes the expressive masks and clusters the frames
(``--tau``), prints one line per keyframe (its representative frame, member count and time range), writes a
contact sheet PNG (one row per keyframe, representative first, expressive regions tinted) and a JSON summary last.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from studio.cli.flags import add_config_flags, config_from_args


def _keyframes(args: argparse.Namespace) -> int:
    from studio.review.sheets import keyframe_sheet, write_png
    from studio.targets.expressive import expressive_masks
    from studio.targets.keyframes import KeyframeConfig, cluster_keyframes
    from studio.targets.path_checks import check_outputs
    from studio.targets.video import VideoConfig, load_video

    src = Path(args.src)
    sheet_path = Path(args.out) / f"{src.stem or 'video'}_keyframes.png"
    check_outputs([sheet_path], inputs=[src], folders=[src] if src.is_dir() else [])  # never a frame of its own
    video = load_video(src, config_from_args(args, VideoConfig))
    expressive = expressive_masks(video.masks)
    clusters = cluster_keyframes(expressive, config_from_args(args, KeyframeConfig), video.masks)
    times = video.times
    for k, (group, rep) in enumerate(zip(clusters.members, clusters.representatives, strict=True)):
        print(
            f"keyframe {k}: frame {rep} (source frame {video.frame_index[rep]}, {times[rep]:.2f} s), "
            f"{len(group)} frame{'s' * (len(group) != 1)}, "
            f"{times[group[0]]:.2f}–{times[group[-1]]:.2f} s"
        )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    sheet = write_png(
        sheet_path,
        keyframe_sheet(video.masks, expressive, clusters.members, clusters.representatives, times=times),
    )
    summary = {
        "frames": len(clusters.assignment),
        "keyframes": clusters.count,
        "assignment": clusters.assignment.tolist(),
        "representatives": clusters.representatives.tolist(),
        "sheet": str(sheet),
    }
    print(json.dumps(summary))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    from studio.targets.keyframes import KeyframeConfig
    from studio.targets.video import VideoConfig

    p = sub.add_parser("keyframes", help="cluster a video's frames into keyframes and write a contact sheet")
    p.add_argument("src", help="video file (mp4, avi, mov, webm, GIF) or folder of frames (PNG/JPEG masks)")
    add_config_flags(p, VideoConfig, ("hz", "fps"))
    add_config_flags(p, KeyframeConfig, ("tau",))
    p.add_argument("--out", default=".", help="folder for the contact sheet SRC_keyframes.png (default: here)")
    p.set_defaults(func=_keyframes)
