"""Hand loading helpers and the self-exploration sampler."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from studio.sim.sampling import SamplerConfig, finger_joint_indices, sample_poses


def test_rest_pose_within_limits(hand):
    rest = hand.rest_pose()
    assert rest.shape == (21,)
    assert np.all(rest >= hand.lower) and np.all(rest <= hand.upper)


def test_pose_dict_round_trip(hand, rng):
    theta = rng.uniform(hand.lower, hand.upper)
    assert np.allclose(hand.pose_from_dict(hand.pose_to_dict(theta)), theta)


def test_pose_dict_names_checked(hand):
    d = hand.pose_to_dict(hand.rest_pose())
    d.pop("wrist")
    d["elbow"] = 0.0
    with pytest.raises(ValueError, match=r"unknown \['elbow'\], missing \['wrist'\]"):
        hand.pose_from_dict(d)


@pytest.mark.parametrize(
    "bad, message",
    [
        (np.zeros(20), "shape"),
        (np.zeros((2, 3, 21)), "shape"),
        (np.full(21, np.nan), "NaN"),
        (np.full(21, 3.0), "outside its limits"),
    ],
)
def test_check_theta_errors(hand, bad, message):
    with pytest.raises(ValueError, match=message):
        hand.check_theta(bad)


def test_sampler_ranges_and_mix(hand):
    n = 20000
    theta, mode = sample_poses(hand, n, np.random.default_rng(0))
    assert theta.shape == (n, 21)
    assert np.all(theta >= hand.lower) and np.all(theta <= hand.upper)
    share = np.bincount(mode, minlength=3) / n
    assert np.allclose(share, [0.75, 0.10, 0.15], atol=0.015)
    # uniform poses cover the whole range of every joint
    uni = theta[mode == 0]
    span = (uni.max(0) - uni.min(0)) / (hand.upper - hand.lower)
    assert np.all(span > 0.98)
    # finger modes: exactly 1 or 2 fingers far from rest, the others near rest
    fingers = finger_joint_indices(hand)
    rest = hand.rest_pose()
    for k, count in ((1, 1), (2, 2)):
        rows = theta[mode == k]
        far = np.stack([np.abs(rows[:, idx] - rest[idx]).max(1) > 0.3 for idx in fingers.values()], 1)
        # an active finger can land near rest by chance; an inactive one stays within 4 sigma of rest
        assert np.all(far.sum(1) <= count)
        assert far.sum(1).mean() > 0.8 * count


def test_sampler_config_validated():
    with pytest.raises(ValueError, match="sum to 1"):
        SamplerConfig(p_uniform=0.5)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 50))
def test_sampler_always_within_limits(hand, seed, n):
    theta, mode = sample_poses(hand, n, np.random.default_rng(seed))
    assert theta.shape == (n, 21) and mode.shape == (n,)
    assert np.all(theta >= hand.lower - 1e-12) and np.all(theta <= hand.upper + 1e-12)
