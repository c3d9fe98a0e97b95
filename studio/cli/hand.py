"""Verbs about the hand itself: ``render`` (a pose's shadow as PNG) and ``gen-urdf`` (regenerate the URDF)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from studio.cli.flags import SEED_RANGE, add_config_flags, config_from_args, ranged
from studio.errors import StudioError
from studio.sim.shadow import Rig
from studio.targets.path_checks import check_outputs


def read_pose_json(path: Path, hand) -> np.ndarray:
    """A pose file: ``{joint_name: rad, ...}`` or ``{"pose": {...}}`` or a list of 21 angles (rad)."""
    from studio.atomic import JsonFileError, read_json

    if not Path(path).is_file():
        raise StudioError(f"{path}: pose file not found (give 'rest', 'random' or a JSON file of joint angles)")
    try:
        data = read_json(path, what="pose file")
    except JsonFileError as e:
        raise StudioError(f"{e} (render takes 'rest', 'random' or a pose file: JSON of joint angles)") from None
    if isinstance(data, dict) and isinstance(data.get("pose"), dict):
        data = data["pose"]
    if isinstance(data, dict):
        return hand.pose_from_dict(data)
    if isinstance(data, list) and len(data) == hand.dof:
        return np.array(data, dtype=float)
    raise StudioError(f"{path}: expected {{joint_name: radians}} or a list of {hand.dof} angles")


def write_shadow_png(path: Path, mask: np.ndarray, as_mask: bool = False) -> None:
    """Save a shadow ``(H, W)`` {0,1}: dark shadow on a light backdrop, or white-on-black with ``as_mask``."""
    import cv2

    from studio.atomic import write_bytes

    img = (mask.astype(np.uint8) * 255) if as_mask else ((1 - mask.astype(np.uint8)) * 255)
    try:
        ok, png = cv2.imencode(Path(path).suffix or ".png", img)
    except cv2.error:
        ok = False
    if not ok:
        raise StudioError(f"{path}: could not encode the image (use a .png extension)")
    write_bytes(path, png.tobytes())  # atomic (studio.atomic)


def _render(args: argparse.Namespace) -> int:
    from studio.sim.hand import load_hand
    from studio.sim.sampling import sample_poses
    from studio.sim.shadow import ShadowRenderer

    pose_file = None if args.pose in ("rest", "random") else Path(args.pose)
    check_outputs([args.out], inputs=[pose_file, args.urdf])
    hand = load_hand(args.urdf)
    if args.pose == "rest":
        theta = hand.rest_pose()
    elif args.pose == "random":
        theta = sample_poses(hand, 1, np.random.default_rng(args.seed))[0][0]
    else:
        theta = read_pose_json(Path(args.pose), hand)
    renderer = ShadowRenderer(hand, config_from_args(args, Rig))
    mask = renderer.render_one(theta)
    write_shadow_png(Path(args.out), mask, as_mask=args.mask)
    print(json.dumps({"out": str(args.out), "shadow_pixels": int(mask.sum()), "pose": hand.pose_to_dict(theta)}))
    return 0


def _gen_urdf(args: argparse.Namespace) -> int:
    from studio.atomic import write_text
    from studio.sim.hand import DEFAULT_URDF
    from studio.sim.handgen import generate_urdf

    text = generate_urdf()
    out = Path(args.out) if args.out else DEFAULT_URDF
    if args.check:
        same = out.is_file() and out.read_text() == text
        print(f"{out}: {'up to date' if same else 'differs from the generator'}")
        return 0 if same else 1
    write_text(out, text)  # atomic (studio.atomic): a URDF is never half-written
    print(f"wrote {out}")
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("render", help="write the shadow of a pose (rest, random, or a JSON file) as PNG")
    p.add_argument("pose", nargs="?", default="rest", help="'rest', 'random', or a JSON file of joint angles (rad)")
    p.add_argument("--out", default="shadow.png", help="PNG file to write (default: shadow.png)")
    add_config_flags(p, Rig, ("resolution", "window"))
    p.add_argument("--seed", type=ranged(int, SEED_RANGE), default=0, metavar="N", help="seed for 'random' (default 0)")
    p.add_argument("--mask", action="store_true", help="write white shadow on black (1 = shadow) instead")
    p.add_argument("--urdf", default=None, help="hand URDF (default: the shipped assets/hand.urdf)")
    p.set_defaults(func=_render)

    g = sub.add_parser("gen-urdf", help="regenerate assets/hand.urdf from studio.sim.handgen (or --check it)")
    g.add_argument("--out", default=None, help="where to write (default: assets/hand.urdf)")
    g.add_argument("--check", action="store_true", help="only check that the file matches the generator")
    g.set_defaults(func=_gen_urdf)
