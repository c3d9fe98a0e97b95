"""The shipped URDF is what the generator makes, and it describes the hand of DESIGN §1."""

from __future__ import annotations

import math

import numpy as np

from studio.sim.hand import DEFAULT_URDF, parse_urdf
from studio.sim.handgen import FINGER_JOINTS, FINGERS, HandSpec, generate_urdf


def test_shipped_urdf_is_generated():
    assert DEFAULT_URDF.read_text() == generate_urdf(), "run `shadow-studio gen-urdf` after changing handgen"


def test_joint_names_order_and_count(hand):
    expected = ["wrist"] + [f"{f}_{j}" for f in FINGERS for j in FINGER_JOINTS]
    assert hand.joint_names == expected
    assert hand.dof == 21
    assert len(hand.link_names) == 22 and hand.root == "forearm"


def test_limits_follow_design(hand):
    lim = {j.name: (math.degrees(j.lower), math.degrees(j.upper)) for j in hand.joints}
    assert np.allclose(lim["wrist"], (-90, 90))
    assert np.allclose(lim["thumb_mcp_abd"], (0, 90))
    for f in ("index", "middle"):
        assert np.allclose(lim[f"{f}_mcp_abd"], (-60, 0))
    for f in ("ring", "pinky"):
        assert np.allclose(lim[f"{f}_mcp_abd"], (0, 60))
    for f in FINGERS:
        for j in ("mcp_flex", "pip", "dip"):
            lo, hi = lim[f"{f}_{j}"]
            assert -90.0 <= lo < 0 < hi <= 90.0


def test_every_link_has_shell_and_moving_links_have_skeleton(hand):
    for name in hand.link_names:
        assert hand.visuals[name], f"{name} has no light-blocking shell"
    for j in hand.joints:
        assert hand.collisions[j.child], f"{j.child} has no collision skeleton"
    # the shell is enlarged relative to the skeleton (foam skin)
    for j in hand.joints:
        shell = max(g.radius for g in hand.visuals[j.child])
        bone = max(g.radius for g in hand.collisions[j.child])
        if hand.collisions[j.child][0].kind == "capsule":
            assert shell > bone


def test_finger_scale_is_servo_hand_sized():
    s = HandSpec()
    finger = s.knuckle_length + s.proximal_length + s.middle_length + s.distal_length
    human_index = 0.085  # metres, MCP to fingertip of an adult index finger
    assert 1.2 <= finger / human_index <= 1.6


def test_parse_rejects_unsupported_geometry():
    text = generate_urdf().replace("<sphere ", "<cylinder length='0.01' ", 1)
    try:
        parse_urdf(text)
    except ValueError as e:
        assert "unsupported geometry" in str(e)
    else:
        raise AssertionError("a cylinder should be rejected")
