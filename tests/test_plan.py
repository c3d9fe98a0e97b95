"""Motion planning: limits, exact keyframes and zero collisions (hypothesis), the three passes on a colliding path,
too-fast segments, keyframe errors, and the CLI verbs."""

from __future__ import annotations

import json
import threading
import time

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from plan_support import (  # the planning tests' own helpers, beside this file
    CROSS_A,
    CROSS_B,
    HAND,
    LIMITS,
    J,
    assert_collision_free,
    assert_keyframes_exact,
    assert_within_limits,
    keyframes,
    pose,
)
from scipy.interpolate import CubicSpline

from studio.cli.main import main
from studio.errors import Cancelled, Progress
from studio.motion.errors import KeyframeCollisionError, PlanCancelled, PlanError, SegmentTooFastError
from studio.motion.limits import JointLimits, LimitsConfig
from studio.motion.path import PathConfig, build_path
from studio.motion.plan import Keyframes, PlanConfig, keyframe_velocities, parse_keyframes, plan_show
from studio.motion.show import load_show
from studio.motion.spline import keyframe_spline, spline_path
from studio.motion.timing import TimingConfig
from studio.sim.hand import DEFAULT_URDF, parse_urdf
from studio.sim.physics import CollisionWorld


@pytest.fixture(scope="module")
def world():
    w = CollisionWorld(HAND)
    yield w
    w.close()


@st.composite
def free_keyframes(draw):
    """2–3 collision-free keyframes (two fingers and the wrist moving) with generous times."""
    rng = np.random.default_rng(draw(st.integers(0, 2**20)))
    n = draw(st.integers(2, 3))
    w = CollisionWorld(HAND)
    poses = []
    while len(poses) < n:
        q = HAND.rest_pose().copy()
        for finger in rng.choice(["thumb", "index", "middle", "ring", "pinky"], 2, replace=False):
            for j in ("mcp_abd", "mcp_flex", "pip", "dip"):
                k = J(f"{finger}_{j}")
                q[k] = rng.uniform(HAND.lower[k], HAND.upper[k]) * 0.7
        q[0] = rng.uniform(-0.8, 0.8)
        if not w.in_collision(q)[0]:
            poses.append(q)
    w.close()
    poses = np.array(poses)
    steps = np.abs(np.diff(np.concatenate([HAND.rest_pose()[None], poses]), axis=0)) / LIMITS.velocity
    times = np.cumsum(1.0 + 3.0 * steps.max(axis=1))
    hold = rng.random(n) < 0.3
    return keyframes(times, poses, hold)


@pytest.mark.slow
@settings(max_examples=10, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kf=free_keyframes())
def test_trajectory_within_limits_exact_keyframes_and_collision_free(world, kf):
    try:
        result = plan_show(HAND, kf, world=world)
    except SegmentTooFastError as e:  # a detour around a collision can need more than the generous time
        assert all(s.feasible > s.requested for s in e.segments)
        result = plan_show(HAND, kf, PlanConfig(timing=TimingConfig(allow_late=True)), world=world)
        assert result.trajectory.late
    assert_within_limits(result.trajectory)
    assert_keyframes_exact(result, kf)
    assert_collision_free(world, result.trajectory)
    assert result.max_jerk_ratio <= 1 + 1e-9
    assert result.show.times[0] == 0 and (np.diff(result.show.times) > 0).all()


def test_passes_repair_a_path_through_a_colliding_region(world):
    assert not world.in_collision(np.stack([CROSS_A, CROSS_B])).any()
    straight = CROSS_A + np.linspace(0, 1, 50)[:, None] * (CROSS_B - CROSS_A)
    assert world.in_collision(straight).any()  # the precondition: interpolation crosses the neighbour
    times, poses = np.array([0.0, 1.0, 4.0]), np.stack([HAND.rest_pose(), CROSS_A, CROSS_B])
    _, spline, _ = spline_path(HAND, times, poses, 40.0)
    assert world.in_collision(np.clip(spline, HAND.lower, HAND.upper)).any()

    path = build_path(HAND, world, times, poses, PathConfig(seed=3))
    assert path.repaired.any()
    assert np.array_equal(path.poses[path.key_index], poses)  # keyframes never perturbed
    assert not world.in_collision(path.poses).any()
    for a, b in zip(path.poses[:-1], path.poses[1:]):  # every straight step is free at 1° spacing
        n = int(np.ceil(np.abs(b - a).max() / np.radians(1.0))) + 1
        assert not world.in_collision(a + np.linspace(0, 1, n)[:, None] * (b - a)).any()

    kf = keyframes(times[1:], poses[1:])
    result = plan_show(HAND, kf, world=world)
    assert_collision_free(world, result.trajectory)
    assert_keyframes_exact(result, kf)
    assert_within_limits(result.trajectory)


@settings(max_examples=40, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**20), n=st.integers(1, 6), spread=st.floats(0.1, 1.0))
@example(seed=44, n=4, spread=0.95)  # this cubic leaves a limit by 1 mrad only between the path's 40 Hz samples
def test_path_and_keyframe_velocities_share_one_spline(seed, n, spread):
    """The path's spline and the keyframe velocities are one spline: a joint interpolated linearly has zero keyframe
    velocity, every other joint the not-a-knot cubic's; the path is exact at keyframes and within the limits
    everywhere, between its 40 Hz samples too (checked at 2 kHz)."""
    rng = np.random.default_rng(seed)
    times = np.concatenate([[0.0], np.cumsum(rng.uniform(0.05, 1.5, n - 1))])
    mid, half = (HAND.lower + HAND.upper) / 2, (HAND.upper - HAND.lower) / 2
    poses = mid + spread * half * rng.uniform(-1, 1, (n, HAND.dof))
    spline = keyframe_spline(times, poses, HAND.lower, HAND.upper)
    t, q, key = spline_path(HAND, times, poses, 40.0)
    assert np.array_equal(q[key], poses) and np.array_equal(t[key], times)
    dense_t = np.linspace(times[0], times[-1], int(2000 * times[-1]) + 2)
    dense = spline(dense_t)
    assert (dense >= HAND.lower - 1e-9).all() and (dense <= HAND.upper + 1e-9).all()
    v = keyframe_velocities(times, poses, np.zeros(n, bool), HAND)
    assert not v[:, spline.linear].any()
    if n < 3:
        assert spline.linear.all()
        return
    cubic = CubicSpline(times, poses, bc_type="not-a-knot", axis=0)
    np.testing.assert_allclose(v[:, ~spline.linear], cubic(times, 1)[:, ~spline.linear])
    c = cubic(dense_t)
    outside = (c < HAND.lower - 1e-9) | (c > HAND.upper + 1e-9)
    assert (outside.any(axis=0) <= spline.linear).all()  # every cubic that leaves its limits falls back
    worst = np.maximum(HAND.lower - c, c - HAND.upper).max(axis=0)
    assert (worst[spline.linear] > -1e-3).all()  # and only those (or ones that touch a limit between samples)


def test_keyframe_spline_fallbacks():
    q0, q1 = pose(index_pip=0.5), pose(index_pip=1.0)
    one = keyframe_spline([2.0], [q0], HAND.lower, HAND.upper)
    assert np.array_equal(one([0.0, 2.0, 5.0]), np.stack([q0] * 3)) and not one.key_velocities().any()
    two = keyframe_spline([0.0, 1.0], [q0, q1], HAND.lower, HAND.upper)
    assert two.linear.all() and np.allclose(two([0.5])[0], (q0 + q1) / 2)
    with pytest.raises(ValueError, match="strictly increasing"):
        keyframe_spline([0.0, 1.0, 1.0], [q0, q1, q0], HAND.lower, HAND.upper)


def test_speed_limits_come_from_the_urdf_alone():
    """The servo speed is stated once, in the URDF: the planner's limits and the player's step limit read it."""
    from hardware.safety import SafetyConfig

    urdf = np.array([j.velocity for j in HAND.joints])
    cfg = LimitsConfig()
    scale = np.where(np.array(HAND.joint_names) == "wrist", cfg.wrist_scale, 1.0)
    np.testing.assert_allclose(LIMITS.velocity, urdf * cfg.velocity_scale * scale)
    np.testing.assert_allclose(LIMITS.jerk, cfg.jerk * scale)
    assert SafetyConfig().max_speed_rad_s == urdf.max()
    text = DEFAULT_URDF.read_text()
    assert 'velocity="' in text
    slow = parse_urdf(text.replace('velocity="', 'velocity="0.5" x="', 1))
    assert JointLimits.from_hand(slow).velocity[0] == pytest.approx(0.5 * cfg.velocity_scale * cfg.wrist_scale)
    with pytest.raises(ValueError, match="no velocity limit"):
        JointLimits.from_hand(parse_urdf(text.replace('velocity="', 'velocity="0" x="', 1)))


def test_too_fast_segment_is_reported_with_its_feasible_time(world):
    far = pose(index_mcp_flex=1.4, middle_mcp_flex=1.4, wrist=1.2)
    kf = keyframes([0.5, 0.6], [far, HAND.rest_pose()], hold=[True, True])
    with pytest.raises(SegmentTooFastError) as e:
        plan_show(HAND, kf, world=world)
    segs = e.value.segments
    assert [s.index for s in segs] == [0, 1]
    assert all(s.feasible > s.requested for s in segs)
    assert "needs at least" in str(e.value) and "allow late transitions" in str(e.value)
    # exactly the reported times are feasible (rest-to-rest segments do not depend on the times)
    t1 = segs[0].feasible + 1e-6
    ok = plan_show(HAND, keyframes([t1, t1 + segs[1].feasible + 1e-6], kf.poses, kf.hold), world=world)
    assert_within_limits(ok.trajectory)
    # allow_late stretches instead, and says so
    late = plan_show(HAND, kf, PlanConfig(timing=TimingConfig(allow_late=True)), world=world)
    assert [s.index for s in late.trajectory.late] == [0, 1]
    assert late.show.provenance["late_segments"][0]["feasible"] == pytest.approx(segs[0].feasible)
    assert late.show.duration == pytest.approx(segs[0].feasible + segs[1].feasible)


# Wrist-only shows in which every move gets its straight rest-to-rest time (+2 %, +0.05 s): the reach rule the
# studio's keyframe boxes keep (studio.motion.reach). Passing every keyframe at the spline's velocity, the planner
# stretched one or two moves of each (a velocity at a keyframe that heads away from the next one costs more time
# than it saves); it now passes such a keyframe at rest instead.
def _crossing(n: int) -> Keyframes:
    """``n`` keyframes 3 s apart swinging the index finger across the middle one and back: every segment needs the
    repair pass and a detour (seconds of planning)."""
    return keyframes(1.0 + 3.0 * np.arange(n), [CROSS_A, CROSS_B] * (n // 2))


def test_a_cancel_stops_planning_promptly_with_a_typed_error(world):
    """Setting the cancel event mid-path raises PlanCancelled (a Cancelled, not a PlanError) well under a second
    later, on a plan that takes seconds; set while timing (a stage later), the same, and no show is sampled."""
    cancel, seen = threading.Event(), []
    timer = threading.Timer(0.3, cancel.set)
    timer.start()
    t0 = time.monotonic()
    with pytest.raises(PlanCancelled, match="cancelled") as e:
        plan_show(HAND, _crossing(4), world=world, progress=seen.append, cancel=cancel)
    late = time.monotonic() - t0 - 0.3
    timer.join()
    assert late < 0.5, late  # the path alone takes ~2 s here
    assert isinstance(e.value, Cancelled) and not isinstance(e.value, PlanError)
    assert all(isinstance(p, Progress) for p in seen) and {p.stage for p in seen} <= {"keyframes", "path"}

    cancel.clear()
    seen.clear()

    def stop_when_timing(p: Progress) -> None:
        seen.append(p)
        if p.stage == "timing":
            cancel.set()

    with pytest.raises(PlanCancelled):
        plan_show(HAND, _crossing(2), world=world, progress=stop_when_timing, cancel=cancel)
    path = [(p.step, p.total) for p in seen if p.stage == "path"]
    assert path == [(1, 4), (2, 4), (3, 4), (4, 4)]  # two segments, the fingertip pass, the corners
    assert [p.stage for p in seen if p.stage not in ("keyframes", "path")] == ["timing"]  # stopped at the next round


def test_colliding_keyframe_is_reported_not_moved(world):
    bad = next(
        CROSS_A + s * (CROSS_B - CROSS_A)
        for s in np.linspace(0, 1, 50)
        if world.in_collision(CROSS_A + s * (CROSS_B - CROSS_A))[0]
    )
    with pytest.raises(KeyframeCollisionError, match=r"t = 2\.000 s \(.*index.*middle"):
        plan_show(HAND, keyframes([1.0, 2.0], [CROSS_A, bad]), world=world)


def test_home_is_added_unless_the_first_keyframe_is_at_zero(world):
    q = pose(index_pip=0.8)
    r = plan_show(HAND, keyframes([1.0], [q]), world=world)
    assert r.home_added and np.array_equal(r.show.positions[0], HAND.rest_pose()) and len(r.show.keyframes) == 1
    r = plan_show(HAND, keyframes([0.0, 1.0], [q, HAND.rest_pose()]), world=world)
    assert not r.home_added and np.array_equal(r.show.positions[0], q)


def test_keyframes_file_errors():
    good = {"t": 1.0, "pose": HAND.pose_to_dict(HAND.rest_pose())}
    with pytest.raises(PlanError, match="keyframes"):
        parse_keyframes({"frames": []}, HAND)
    with pytest.raises(PlanError, match="unknown"):
        parse_keyframes({"keyframes": [{"t": 1.0, "pose": {**good["pose"], "elbow": 0.0}}]}, HAND)
    with pytest.raises(PlanError, match="not after"):
        parse_keyframes({"keyframes": [good, good]}, HAND)
    with pytest.raises(PlanError, match="outside its limits"):
        parse_keyframes({"keyframes": [{"t": 1.0, "pose": {**good["pose"], "wrist": 3.0}}]}, HAND)
    kf = parse_keyframes({"keyframes": [{**good, "hold": True, "source_frame": 4, "loss": 0.3}], "title": "x"}, HAND)
    assert kf.hold.tolist() == [True] and kf.source_frame == [4] and kf.extra["keyframe_losses"] == [0.3]


def test_cli_plan_validate_info_csv(tmp_path, capsys):
    poses = tmp_path / "POSES.json"
    frames = [{"t": 0.8, "pose": HAND.pose_to_dict(pose(ring_pip=1.0))}, {"t": 1.6, "pose": HAND.pose_to_dict(pose())}]
    poses.write_text(json.dumps({"keyframes": frames, "title": "cli"}))
    out = tmp_path / "show.json"
    assert main(["plan", str(poses), "--out", str(out), "--csv", str(tmp_path / "a.csv")]) == 0
    assert load_show(out, HAND).title == "cli" and (tmp_path / "a.csv").is_file()
    assert main(["validate", str(out)]) == 0
    assert main(["show-info", str(out)]) == 0
    assert "keyframes:    2 keyframes, on the show clock at 0.80 s, 1.60 s" in capsys.readouterr().out
    assert main(["export-csv", str(out), "--out", str(tmp_path / "b.csv"), "--degrees"]) == 0
    frames[0]["t"] = 0.05  # too fast: one clear line, exit 2
    poses.write_text(json.dumps({"keyframes": frames}))
    assert main(["plan", str(poses), "--out", str(tmp_path / "late.json")]) == 2
    assert "too fast" in capsys.readouterr().err
    out.write_text(out.read_text()[:500])
    assert main(["validate", str(out)]) == 2
    assert "not valid JSON" in capsys.readouterr().err
