"""Online jerk-limited motion (studio.motion.online) with the real Ruckig: against Ruckig's offline trajectory, and
within the joints' limits while the target changes."""

from __future__ import annotations

import numpy as np
import pytest
from ruckig import InputParameter, OutputParameter, Result, Ruckig, RuckigError, Trajectory

from studio.motion.errors import MotionError
from studio.motion.limits import JointLimits
from studio.motion.online import OnlineConfig, OnlineMotion
from studio.sim.hand import load_hand

DT = 1 / 40


@pytest.fixture(scope="module")
def limits() -> JointLimits:
    return JointLimits.from_hand(load_hand())


@pytest.fixture(scope="module")
def rest(limits) -> np.ndarray:
    return np.clip(load_hand().rest_pose(), limits.lower, limits.upper)


def _inside(limits: JointLimits, q: np.ndarray) -> np.ndarray:
    return np.clip(q, limits.lower, limits.upper)


def _offline(limits: JointLimits, m: OnlineMotion, goal: np.ndarray, scale: float = 1.0) -> Trajectory:
    """The slow reference: Ruckig's offline trajectory from ``m``'s state to ``goal`` at rest."""
    n = len(goal)
    inp = InputParameter(n)
    inp.current_position, inp.current_velocity = m.position.tolist(), m.velocity.tolist()
    inp.current_acceleration = m.acceleration.tolist()
    inp.target_position, inp.target_velocity, inp.target_acceleration = goal.tolist(), [0.0] * n, [0.0] * n
    inp.max_velocity = (limits.velocity * scale).tolist()
    inp.max_acceleration = (limits.acceleration * scale).tolist()
    inp.max_jerk = (limits.jerk * scale).tolist()
    traj = Trajectory(n)
    assert Ruckig(n).calculate(inp, traj) == Result.Working
    return traj


def _follow(m: OnlineMotion, traj: Trajectory, ticks: int) -> None:
    for k in range(1, ticks + 1):
        q = m.step()
        ref = np.array(traj.at_time(min(k * DT, traj.duration))[0])
        assert np.abs(q - ref).max() < 1e-6, f"tick {k}: {np.abs(q - ref).max():.2e} rad from the reference"


@pytest.mark.parametrize("scale", [1.0, 0.4])
def test_online_steps_follow_the_offline_trajectory(limits, rest, scale):
    """Fast path vs reference: an unchanged target gives Ruckig's offline trajectory sampled at the ticks, from
    rest and from a moving state (after a target change mid-move)."""
    rng = np.random.default_rng(0)
    m = OnlineMotion(limits, rest, OnlineConfig(speed_scale=scale))
    goal = m.set_target(rest + rng.uniform(-0.8, 0.8, len(rest)))
    traj = _offline(limits, m, goal, scale)
    _follow(m, traj, 9)  # mid-move
    assert np.abs(m.velocity).max() > 0.1
    goal = m.set_target(rest - rng.uniform(-0.8, 0.8, len(rest)))
    traj = _offline(limits, m, goal, scale)
    _follow(m, traj, int(traj.duration / DT) + 3)
    assert m.at_target and np.allclose(m.position, goal, rtol=0, atol=1e-12)


def test_changing_targets_stay_within_every_limit(limits, rest):
    """Seeded random targets changed every few ticks, every other one reversing: velocity, acceleration and jerk stay
    within the limits, both in Ruckig's state and as finite differences of the returned positions."""
    rng = np.random.default_rng(1)
    m = OnlineMotion(limits, rest)
    q, vel, acc = [m.position], [], []
    goal = rest
    for k in range(600):
        if k % int(rng.integers(2, 12)) == 0 or k == 0:
            step = rng.uniform(0.3, 1.2, len(rest)) * rng.choice([-1, 1], len(rest))
            goal = _inside(limits, rest + (step if k % 2 else -np.sign(goal - rest) * np.abs(step)))
            m.set_target(goal)
        q.append(m.step())
        vel.append(m.velocity)
        acc.append(m.acceleration)
    q = np.array(q)
    assert (q >= limits.lower).all() and (q <= limits.upper).all()
    assert (np.abs(vel) <= limits.velocity * (1 + 1e-9)).all()
    assert (np.abs(acc) <= limits.acceleration * (1 + 1e-9)).all()
    for order, bound in ((1, limits.velocity), (2, limits.acceleration), (3, limits.jerk)):
        d = np.abs(np.diff(q, n=order, axis=0)) / DT**order
        assert (d <= bound * 1.001 + 1e-6).all(), f"derivative {order} beyond its limit: {(d / bound).max():.4f}×"
    assert (np.abs(vel) > 0.5 * limits.velocity).any(), "it moved fast enough to test the limits"
    assert (np.diff(np.sign(np.array(vel)), axis=0) != 0).any(), "some joint reversed mid-move"


def test_reversal_mid_move_is_smooth(limits, rest):
    """A target flipped to the other side while moving at speed: velocity passes through zero without a jump."""
    m = OnlineMotion(limits, rest)
    up = m.set_target(rest + 1.0)
    moving = up > rest + 0.5
    for _ in range(12):
        m.step()
    assert (m.velocity[moving] > 0.3 * limits.velocity[moving]).all()
    m.set_target(rest - 1.0)
    v = [m.velocity]
    while not m.at_target:
        m.step()
        v.append(m.velocity)
    v = np.array(v)
    assert (np.abs(np.diff(v, axis=0)) <= limits.acceleration * DT * (1 + 1e-9)).all()
    assert (np.abs(v[-1]) <= 1e-9).all() and (v[:, moving].min(axis=0) < 0).all(), "came back from the other side"


def test_reaches_the_target_and_is_deterministic(limits, rest):
    rng = np.random.default_rng(2)
    targets = [_inside(limits, rest + rng.uniform(-1, 1, len(rest))) for _ in range(8)]

    def run() -> np.ndarray:
        m = OnlineMotion(limits, rest)
        out = []
        for t in targets:
            m.set_target(t)
            out += [m.step() for _ in range(5)]
        assert not m.at_target
        for _ in range(400):
            out.append(m.step())
            if m.at_target:
                break
        assert m.at_target and np.abs(m.position - targets[-1]).max() <= 1e-6
        assert np.array_equal(m.step(), _inside(limits, m.position)), "holds at rest on the target"
        return np.array(out)

    assert np.array_equal(run(), run())


def test_targets_and_start_are_clipped_and_checked(limits, rest):
    m = OnlineMotion(limits, limits.lower - 0.3)
    assert np.array_equal(m.position, limits.lower) and m.at_target, "start clipped into the limits"
    far = limits.upper + 1.0
    assert np.array_equal(m.set_target(far), limits.upper) and np.array_equal(m.target, limits.upper)
    for _ in range(400):
        q = m.step()
    assert m.at_target and np.allclose(q, limits.upper, atol=1e-9) and (q <= limits.upper).all()
    bad = rest.copy()
    bad[3] = np.nan
    for theta, match in ((bad, "non-finite"), (np.zeros(5), "shape"), (np.zeros((1, len(rest))), "shape")):
        with pytest.raises(ValueError, match=match):
            m.set_target(theta)
    assert np.array_equal(m.target, limits.upper), "a refused target leaves the old one"
    with pytest.raises(ValueError, match="shape"):
        OnlineMotion(limits, np.zeros(3))


def test_reset_puts_it_at_rest(limits, rest):
    m = OnlineMotion(limits, rest)
    m.set_target(rest + 0.5)
    for _ in range(5):
        m.step()
    assert np.abs(m.velocity).max() > 0 and np.abs(m.acceleration).max() > 0
    here = m.position + 0.01
    m.reset(here)
    assert m.at_target and np.array_equal(m.position, _inside(limits, here))
    assert np.array_equal(m.target, m.position)
    assert not m.velocity.any() and not m.acceleration.any()
    assert np.array_equal(m.step(), _inside(limits, here)), "holds there"


def test_speed_scale_and_slower_limits_slow_it_down(limits, rest):
    goal = rest + 0.6

    def ticks(m: OnlineMotion) -> int:
        m.set_target(goal)
        for k in range(2000):
            m.step()
            assert (np.abs(m.velocity) <= m.limits.velocity * m.cfg.speed_scale * (1 + 1e-9)).all()
            if m.at_target:
                return k
        raise AssertionError("never arrived")

    full = ticks(OnlineMotion(limits, rest))
    half = ticks(OnlineMotion(limits, rest, OnlineConfig(speed_scale=0.5)))
    slow = OnlineMotion(limits, rest)
    slow.limits = slow.slower(0.2)
    crawl = ticks(slow)
    assert full < half < crawl
    for bad in (dict(speed_scale=0.0), dict(speed_scale=1.5), dict(rate_hz=0.0)):
        with pytest.raises(ValueError):
            OnlineConfig(**bad)


def test_ruckig_failure_raises_motion_error_and_keeps_the_state(limits, rest):
    """Limits so small that the move outlasts what Ruckig can time: a typed error naming the state, no step."""
    m = OnlineMotion(limits, rest, OnlineConfig(speed_scale=1e-6))
    m.set_target(rest + 1.0)
    with pytest.raises(MotionError, match=r"from position .* rad, velocity .* toward .*raise speed_scale"):
        m.step()
    assert np.array_equal(m.position, rest) and not m.velocity.any()
    with pytest.raises(MotionError):  # still refused on the next tick, never a silent step
        m.step()
    m.reset(rest)
    assert np.array_equal(m.step(), rest)


def _plain_ruckig_fails(m: OnlineMotion, limits: JointLimits) -> bool:
    """Whether Ruckig itself, given ``m``'s raw state and target, refuses to step (the case settling avoids)."""
    n = len(m.position)
    inp, out = InputParameter(n), OutputParameter(n)
    inp.current_position, inp.current_velocity = m.position.tolist(), m.velocity.tolist()
    inp.current_acceleration, inp.target_position = m.acceleration.tolist(), m.target.tolist()
    inp.max_velocity, inp.max_acceleration = limits.velocity.tolist(), limits.acceleration.tolist()
    inp.max_jerk = limits.jerk.tolist()
    try:
        return Ruckig(n, DT).update(inp, out) not in (Result.Working, Result.Finished)
    except (RuckigError, RuntimeError, ValueError):
        return True


def test_floating_point_residues_at_the_target_settle_instead_of_failing(limits, rest):
    """A held pose after replans leaves residues (1e-16..1e-11 rad, 1e-15..1e-9 rad/s) that plain Ruckig refuses
    ("error in step 2 ... t sync: 0", seen live in CI): each such joint settles exactly on its target, at rest,
    while a joint still on its way keeps moving."""
    rng = np.random.default_rng(0)
    n, refused = len(rest), 0
    for trial in range(200):
        m = OnlineMotion(limits, rest)
        goal = _inside(limits, rest + rng.normal(0, 1, n) * 10.0 ** rng.uniform(-16, -11))
        moving = trial % 2 == 1  # odd trials: joint 3 still has far to go
        if moving:
            goal[3] = _inside(limits, rest + 0.3)[3]
        m.set_target(goal)
        m._inp.current_velocity = (rng.normal(0, 1, n) * 10.0 ** rng.uniform(-15, -9)).tolist()  # the residue
        refused += _plain_ruckig_fails(m, limits)
        q = m.step()
        settled = np.arange(n) != 3 if moving else np.ones(n, bool)
        assert np.array_equal(q[settled], goal[settled]), f"trial {trial}: a residue joint left its target"
        assert not m.velocity[settled].any()
        if moving:
            assert q[3] > rest[3] and m.velocity[3] > 0
    assert refused >= 3, "plain Ruckig accepted (nearly) every case: the residues no longer reproduce the failure"
