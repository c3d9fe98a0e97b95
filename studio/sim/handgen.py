"""Parametric description of the 21-DoF shadow hand and its URDF generator.

The shipped ``assets/hand.urdf`` is exactly ``generate_urdf(HandSpec())``; a test holds them together and
``shadow-studio gen-urdf`` rewrites the file. Everything else reads the URDF, never this module's numbers.

Frames (DESIGN §1): palm centre at the world origin, +z towards the light, +y up (fingers point +y at rest),
+x to the audience's right. The wrist turns the palm about the forearm axis (+y). Each finger link's own
frame has +y along the bone and +x as the flexion axis, so positive flexion curls the finger towards the
palm side (+z, the light) and positive abduction turns it about the palm normal.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

FINGERS = ("thumb", "index", "middle", "ring", "pinky")
FINGER_JOINTS = ("mcp_abd", "mcp_flex", "pip", "dip")


@dataclass(frozen=True)
class FingerMount:
    """Where a finger's abduction joint sits on the palm (palm frame)."""

    xyz: tuple[float, float, float]  # knuckle position on the palm, metres
    rpy: tuple[float, float, float]  # mount orientation (URDF fixed-axis roll, pitch, yaw), radians
    abd_limits_deg: tuple[float, float]  # MCP abduction range, degrees (DESIGN §1 sampling ranges)


@dataclass(frozen=True)
class HandSpec:
    """Every dimension of the hand, in metres and degrees. Paper-like servo-scale defaults."""

    palm_collision: tuple[float, float, float] = (0.084, 0.094, 0.022)  # palm skeleton box size x, y, z
    palm_shell: tuple[float, float, float] = (0.104, 0.110, 0.036)  # palm light-blocking box size x, y, z
    wrist_shell_radius: float = 0.030  # radius of the wrist stub's shell capsule below the palm
    wrist_shell_length: float = 0.040  # length of the wrist stub (from the palm's lower edge downwards)
    knuckle_length: float = 0.012  # offset from the abduction axis to the flexion axis
    proximal_length: float = 0.050  # MCP flexion axis to PIP axis (about 1.25x a human index)
    middle_length: float = 0.032  # PIP axis to DIP axis
    distal_length: float = 0.026  # DIP axis to fingertip
    bone_radius: float = 0.0075  # collision skeleton capsule radius of every finger bone
    knuckle_radius: float = 0.0085  # collision sphere radius at each abduction joint
    shell_radius: float = 0.012  # light-blocking foam shell capsule radius (soft TPU skin)
    wrist_limits_deg: tuple[float, float] = (-90.0, 90.0)  # wrist rotation about the forearm axis
    flex_limits_deg: tuple[float, float] = (-90.0, 90.0)  # MCP flexion, PIP and DIP range
    effort: float = 1.5  # joint effort limit, N m (LX-15D stall torque ~1.7 N m)
    velocity: float = 5.2  # joint velocity limit, rad/s (LX-15D: 0.2 s per 60 deg at 7.4 V)
    mounts: dict[str, FingerMount] = field(
        default_factory=lambda: {
            # The thumb sits low on the +x side, turned outwards and rolled so that flexion crosses the palm.
            "thumb": FingerMount((0.048, -0.026, 0.012), (0.0, math.radians(-60), math.radians(-60)), (0.0, 90.0)),
            "index": FingerMount((0.0375, 0.056, 0.0), (0.0, 0.0, 0.0), (-60.0, 0.0)),
            "middle": FingerMount((0.0125, 0.056, 0.0), (0.0, 0.0, 0.0), (-60.0, 0.0)),
            "ring": FingerMount((-0.0125, 0.056, 0.0), (0.0, 0.0, 0.0), (0.0, 60.0)),
            "pinky": FingerMount((-0.0375, 0.056, 0.0), (0.0, 0.0, 0.0), (0.0, 60.0)),
        }
    )  # per-finger mount on the palm


def _f(x: float) -> str:
    """Format a number for the URDF: fixed precision so the output is byte-stable."""
    s = f"{x:.6f}".rstrip("0").rstrip(".")
    return "0" if s in ("-0", "") else s


def _v(values: tuple[float, ...] | list[float]) -> str:
    return " ".join(_f(v) for v in values)


# A capsule along +y of its link frame: URDF capsules lie along the origin's z axis, so roll -90 deg.
_ALONG_Y = (-math.pi / 2, 0.0, 0.0)


def _capsule(tag: str, start_y: float, end_y: float, radius: float) -> str:
    """A capsule whose segment runs from y=start_y to y=end_y in the link frame (caps extend by radius)."""
    return (
        f"    <{tag}>\n"
        f'      <origin xyz="0 {_f((start_y + end_y) / 2)} 0" rpy="{_v(_ALONG_Y)}"/>\n'
        f'      <geometry><capsule radius="{_f(radius)}" length="{_f(end_y - start_y)}"/></geometry>\n'
        f"{_material(tag)}"
        f"    </{tag}>\n"
    )


def _material(tag: str) -> str:
    if tag != "visual":
        return ""
    return '      <material name="shell"><color rgba="0.15 0.15 0.15 1"/></material>\n'


def _box(tag: str, size: tuple[float, float, float], center=(0.0, 0.0, 0.0)) -> str:
    return (
        f"    <{tag}>\n"
        f'      <origin xyz="{_v(center)}" rpy="0 0 0"/>\n'
        f'      <geometry><box size="{_v(size)}"/></geometry>\n'
        f"{_material(tag)}"
        f"    </{tag}>\n"
    )


def _sphere(tag: str, radius: float) -> str:
    return (
        f"    <{tag}>\n"
        f'      <origin xyz="0 0 0" rpy="0 0 0"/>\n'
        f'      <geometry><sphere radius="{_f(radius)}"/></geometry>\n'
        f"{_material(tag)}"
        f"    </{tag}>\n"
    )


def _inertial(mass: float) -> str:
    i = _f(mass * 1e-4)
    return (
        "    <inertial>\n"
        f'      <mass value="{_f(mass)}"/>\n'
        f'      <inertia ixx="{i}" ixy="0" ixz="0" iyy="{i}" iyz="0" izz="{i}"/>\n'
        "    </inertial>\n"
    )


def _link(name: str, body: str, mass: float) -> str:
    return f'  <link name="{name}">\n{_inertial(mass)}{body}  </link>\n'


def _joint(name, parent, child, xyz, rpy, axis, limits_rad, spec: HandSpec) -> str:
    return (
        f'  <joint name="{name}" type="revolute">\n'
        f'    <parent link="{parent}"/>\n'
        f'    <child link="{child}"/>\n'
        f'    <origin xyz="{_v(xyz)}" rpy="{_v(rpy)}"/>\n'
        f'    <axis xyz="{_v(axis)}"/>\n'
        f'    <limit lower="{_f(limits_rad[0])}" upper="{_f(limits_rad[1])}" '
        f'effort="{_f(spec.effort)}" velocity="{_f(spec.velocity)}"/>\n'
        "  </joint>\n"
    )


def _deg(limits: tuple[float, float]) -> tuple[float, float]:
    return (math.radians(limits[0]), math.radians(limits[1]))


def generate_urdf(spec: HandSpec | None = None) -> str:
    """The URDF text of the hand described by ``spec`` (defaults: the shipped hand)."""
    s = spec or HandSpec()
    out = ['<?xml version="1.0"?>\n', "<!-- Generated by studio.sim.handgen.generate_urdf; do not edit by hand. -->\n"]
    out.append('<robot name="shadow_hand_21dof">\n')
    # The forearm is the fixed base; its shell is the wrist stub that shows below the palm.
    half_y = s.palm_shell[1] / 2
    stub = _capsule("visual", -half_y - s.wrist_shell_length, -half_y, s.wrist_shell_radius)
    out.append(_link("forearm", stub, 0.3))
    palm_body = _box("collision", s.palm_collision) + _box("visual", s.palm_shell)
    out.append(_link("palm", palm_body, 0.2))
    out.append(_joint("wrist", "forearm", "palm", (0, 0, 0), (0, 0, 0), (0, 1, 0), _deg(s.wrist_limits_deg), s))
    bones = (("proximal", s.proximal_length), ("middle", s.middle_length), ("distal", s.distal_length))
    for finger in FINGERS:
        m = s.mounts[finger]
        knuckle = f"{finger}_knuckle"
        body = _sphere("collision", s.knuckle_radius) + _capsule("visual", 0.0, s.knuckle_length, s.shell_radius)
        out.append(_link(knuckle, body, 0.02))
        axis_z = (0, 0, 1)
        out.append(_joint(f"{finger}_mcp_abd", "palm", knuckle, m.xyz, m.rpy, axis_z, _deg(m.abd_limits_deg), s))
        parent, offset = knuckle, s.knuckle_length
        for (bone, length), jname in zip(bones, ("mcp_flex", "pip", "dip")):
            child = f"{finger}_{bone}"
            r = s.bone_radius
            body = _capsule("collision", r, length - r, r) + _capsule("visual", 0.0, length, s.shell_radius)
            out.append(_link(child, body, 0.02))
            flex = _deg(s.flex_limits_deg)
            out.append(_joint(f"{finger}_{jname}", parent, child, (0, offset, 0), (0, 0, 0), (1, 0, 0), flex, s))
            parent, offset = child, length
    out.append("</robot>\n")
    return "".join(out)
