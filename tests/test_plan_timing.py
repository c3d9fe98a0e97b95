"""The timing's answers where a straight move collides or a path check falls short: moves given their rest-to-rest
time, one via-point near a colliding straight move (``studio.motion.via_search``), a point beside a thin collision
(``studio.motion.sidestep``), and motions between two rests that stay on their checked line."""

from __future__ import annotations

import threading

import numpy as np
import pytest
from plan_support import (  # the planning tests' own helpers, beside this file
    CROSS_A,
    CROSS_B,
    HAND,
    LIMITS,
    assert_collision_free,
    assert_keyframes_exact,
    assert_within_limits,
    keyframes,
    pose,
)

from studio.motion.errors import PathError, PlanCancelled, SegmentTooFastError
from studio.motion.path import Path
from studio.motion.plan import PlanConfig, plan_show
from studio.motion.reach import rest_to_rest_time
from studio.motion.segment_timer import RuckigSolver, SegmentTimer, colliding, evaluate
from studio.motion.sidestep import SidestepConfig, insert_point, sidestep
from studio.motion.timing import TimingConfig
from studio.motion.via_search import ViaSearch, via_detour
from studio.sim.physics import CollisionWorld


@pytest.fixture(scope="module")
def world():
    w = CollisionWorld(HAND)
    yield w
    w.close()


REACH_SHOWS = [(-0.34, 1.226, -0.857, 0.387), (-0.758, -0.812, 1.219, -0.861), (0.689, -1.521, 0.81, 0.04)]


@pytest.mark.parametrize("wrist", REACH_SHOWS)
def test_moves_given_their_rest_to_rest_time_are_never_late(world, wrist):
    poses = [pose(wrist=w) for w in wrist]
    times = [1.0]
    for a, b in zip(poses, poses[1:], strict=False):
        times.append(times[-1] + 1.02 * float(rest_to_rest_time(b - a, LIMITS).max()) + 0.05)
    got = plan_show(HAND, keyframes(times, poses), world=world)  # SegmentTooFastError when a move is late
    assert got.trajectory.late == [] and got.show.duration == pytest.approx(times[-1])
    assert np.allclose(got.trajectory.state(np.asarray(times))[0], poses, atol=1e-6)
    assert_within_limits(got.trajectory)


@pytest.mark.parametrize("tries", [ViaSearch().tries, 0])
def test_a_crossing_move_given_its_rest_to_rest_time_is_not_late(world, tries):
    """The index finger swinging across the middle one, given 1.02 × its straight rest-to-rest time: the straight
    move collides, and the repaired path's corners need 2.4 s for its 0.89 s. One via-point near the straight move
    (``studio.motion.via_search``) makes it in time, collision-free; without the search (``tries`` 0) it is late."""
    t1 = 1.0 + 1.02 * float(rest_to_rest_time(CROSS_A - HAND.rest_pose(), LIMITS).max()) + 0.05
    t2 = t1 + 1.02 * float(rest_to_rest_time(CROSS_B - CROSS_A, LIMITS).max()) + 0.05
    kf = keyframes([t1, t2], [CROSS_A, CROSS_B])
    cfg = PlanConfig(timing=TimingConfig(via=ViaSearch(tries=tries)))
    if not tries:
        with pytest.raises(SegmentTooFastError, match="segment 1"):
            plan_show(HAND, kf, cfg, world=world)
        return
    got = plan_show(HAND, kf, cfg, world=world)
    assert got.trajectory.late == [] and got.show.duration == pytest.approx(t2)
    assert_collision_free(world, got.trajectory)
    assert_keyframes_exact(got, kf)
    assert_within_limits(got.trajectory)
    again = plan_show(HAND, kf, cfg, world=world)  # seeded: the same plan
    assert np.array_equal(again.show.positions, got.show.positions)


@pytest.mark.parametrize("stretch", [1.0, 1.3, 3.0])
def test_a_motion_between_rests_stays_on_its_straight_line_however_long_it_is_given(stretch):
    """``RuckigSolver.solve(..., straight=True)``: Ruckig's own ``minimum_duration`` reshapes each joint's profile and
    leaves the line (up to 0.014 rad here); slowed down evenly, the motion stays on it, ends on time at rest, and keeps
    every limit."""
    solver, rng, zero = RuckigSolver(LIMITS), np.random.default_rng(3), np.zeros(HAND.dof)
    for _ in range(20):
        a = rng.uniform(HAND.lower, HAND.upper)
        b = np.clip(a + rng.normal(0.0, 0.15, HAND.dof), HAND.lower, HAND.upper)
        span = stretch * solver.solve(a, zero, b, zero, None, straight=True).duration
        tr = solver.solve(a, zero, b, zero, span, straight=True)
        given = solver.solve(a, zero, b, zero, span, straight=True, shortest=span / stretch)  # the caller's shortest
        assert given.duration == pytest.approx(tr.duration, rel=1e-12)
        assert np.allclose(given.at_time(0.4 * span)[0], tr.at_time(0.4 * span)[0], atol=1e-12)
        assert tr.duration == pytest.approx(span, rel=1e-9, abs=1e-12)
        t = np.linspace(0.0, tr.duration, 80)
        pos, vel, acc = (np.array([tr.at_time(x)[i] for x in t]) for i in range(3))
        u = (pos - a) @ (b - a) / ((b - a) @ (b - a))
        assert np.abs(pos - (a + u[:, None] * (b - a))).max() < 1e-9 and (np.diff(u) >= -1e-12).all()
        assert np.allclose(pos[-1], b, atol=1e-9) and np.abs(vel[-1]).max() < 1e-9
        assert (np.abs(vel) <= LIMITS.velocity * (1 + 1e-9)).all() and (
            np.abs(acc) <= LIMITS.acceleration * (1 + 1e-9)
        ).all()
    hold = solver.solve(a, zero, a, zero, 1.0, straight=True)  # no line to follow: a hold at rest
    assert hold is not None and np.allclose(hold.at_time(0.5)[0], a)


def test_the_via_search_fits_the_span_exactly_refuses_the_impossible_and_stops_on_cancel(world):
    """``via_detour`` on the crossing move: pieces that start at t0, end at t0 + span on the keyframe, collision-free;
    None for a span shorter than the straight rest-to-rest move (no via beats it); PlanCancelled once cancelled."""
    timer = SegmentTimer(RuckigSolver(LIMITS), LIMITS)
    zero, straight = np.zeros(HAND.dof), float(rest_to_rest_time(CROSS_B - CROSS_A, LIMITS).max())
    span = 1.05 * straight
    pieces, checks = via_detour(timer, world, 2.0, span, (CROSS_A, CROSS_B), (zero, zero), 160.0)
    assert pieces is not None and checks > 0 and pieces[0].t0 == 2.0
    assert pieces[-1].t0 + pieces[-1].duration == pytest.approx(2.0 + span)
    end = evaluate(pieces, np.array([2.0, 2.0 + span]))[0]
    assert np.allclose(end, [CROSS_A, CROSS_B], atol=1e-6)
    assert not colliding(world, pieces, 2.0, 2.0 + span, 160.0)[1].any()
    assert via_detour(timer, world, 2.0, 0.9 * straight, (CROSS_A, CROSS_B), (zero, zero), 160.0)[0] is None
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(PlanCancelled):
        via_detour(timer, world, 2.0, span, (CROSS_A, CROSS_B), (zero, zero), 160.0, cancel=cancel)
    for bad in ({"tries": -1}, {"checked": -1}, {"spreads": ()}, {"spreads": (0.1, 0.0)}):
        with pytest.raises(ValueError, match="via search"):
            ViaSearch(**bad)


# bench_crossing.py's show 12 of seed 2 at factor 1.02 (rounded): its path's 2° check steps over a 0.7° contact (the
# ring finger's tip 6.5 µm into the pinky) that the trajectory's 160 Hz check meets between two adjacent path points
THIN_A = np.array([0.7762, 1.0571, -0.0038, 1.0656, 0.8408, -0.3612, -0.742, -1.2658, -0.8906, -0.2791, -1.1245,
                   -0.2757, 0.8564, 0.7486, -0.5166, 0.8116, 0.4717, 0.3209, 0.1416, 0.129, 0.5744])  # fmt: skip
THIN_B = np.array([0.0298, 0.582, -0.3716, -0.4358, -0.9633, -0.7602, -0.7687, 0.6812, 1.0593, -0.9192, 1.1537,
                   1.2415, -0.3399, 0.438, 0.5837, 0.9041, 1.2217, 0.5326, -0.5703, -0.1116, 0.1829])  # fmt: skip


@pytest.mark.parametrize("tries", [SidestepConfig().tries, 0])
def test_a_thin_collision_between_path_points_gets_a_point_beside_it(world, tries):
    """Where the trajectory meets a contact between two adjacent path points, the timing adds one point beside it
    (``studio.motion.sidestep``): the show plans collision-free (checked at 1,000 Hz), its late move reported as
    such; without the sidestep (``tries`` 0) the same show fails with a PathError."""
    kf = keyframes([1.757, 2.704], [THIN_A, THIN_B])
    cfg = PlanConfig(timing=TimingConfig(allow_late=True, sidestep=SidestepConfig(tries=tries)))
    if not tries:
        with pytest.raises(PathError, match="collides even along the repaired path"):
            plan_show(HAND, kf, cfg, world=world)
        return
    got = plan_show(HAND, kf, cfg, world=world)
    assert [s.index for s in got.trajectory.late] == [1]  # the move needs 2.7 s of its 0.95: late, and said so
    assert_collision_free(world, got.trajectory, rate=1000.0)
    assert_keyframes_exact(got, kf)
    assert_within_limits(got.trajectory)
    path = got.path  # the added point is in the path, and the keyframes are where its indices say
    assert np.array_equal(path.poses[path.key_index[1:]], kf.poses) and len(path.times) == len(path.poses)
    assert (np.diff(path.times) > 0).all()
    with pytest.raises(SegmentTooFastError, match="segment 1"):  # without --allow-late: too fast, not a failure
        plan_show(HAND, kf, PlanConfig(), world=world)


def test_sidestep_finds_a_free_point_with_free_halves_and_insert_point_keeps_the_path_consistent(world):
    line = CROSS_A + np.linspace(0.0, 1.0, 200)[:, None] * (CROSS_B - CROSS_A)
    near = line[np.flatnonzero(world.in_collision(line))[0]]
    m, checks = sidestep(world, CROSS_A, CROSS_B, near, SidestepConfig())
    assert m is not None and checks > 0 and not world.in_collision(m[None])[0]
    for a, b in ((CROSS_A, m), (m, CROSS_B)):
        s = np.linspace(0.0, 1.0, 400)[:, None]
        assert not world.in_collision(a + s * (b - a)).any()
    again, _ = sidestep(world, CROSS_A, CROSS_B, near, SidestepConfig())  # seeded
    assert np.array_equal(again, m)
    assert sidestep(world, CROSS_A, CROSS_B, near, SidestepConfig(tries=0)) == (None, 0)
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(PlanCancelled):
        sidestep(world, CROSS_A, CROSS_B, near, SidestepConfig(), cancel)
    for bad in ({"tries": -1}, {"fine_deg": 0.0}, {"fine_deg": 3.0}, {"spreads": ()}, {"spreads": (0.1, -0.1)}):
        with pytest.raises(ValueError, match="sidestep"):
            SidestepConfig(**bad)
    poses = np.stack([HAND.rest_pose(), CROSS_A, CROSS_B])
    flags = np.zeros(3, bool)
    path = Path(np.array([0.0, 1.0, 2.0]), poses, np.array([0, 2]), flags.copy(), flags.copy(), np.ones(3, bool))
    insert_point(path, 1, m)
    assert np.array_equal(path.times, [0.0, 1.0, 1.5, 2.0]) and np.array_equal(path.poses[2], m)
    assert np.array_equal(path.key_index, [0, 3]) and np.array_equal(path.poses[path.key_index[1]], CROSS_B)
    assert path.repaired.tolist() == [False, False, True, False] and path.corner.all() and not path.refined.any()
