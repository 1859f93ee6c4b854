"""The prediction's per-axis persistence (motion_persistence.hpp, registration.persistence_window): the
least-squares a in v(k+1) ~ a v(k) over the registered frames' velocities, clamped to [0, 1], through the engine's
testing module, then end to end on TUM fr1/xyz (test_odometry_tum.py)."""
import numpy as np
import pytest

import line_odom_core
from line_odom.datasets import tum_sequence
from line_odom_core import _testing

MIN_PAIRS = 10  # MotionPersistence::kMinPairs: constant velocity until then


def ar1(alpha, frames, seed=0, scale=1.0):
    """Motions of an AR(1) process v(k+1) = alpha v(k) + w, w ~ N(0, scale^2), on every axis."""
    rng = np.random.default_rng(seed)
    v = np.zeros((frames, 6))
    for k in range(1, frames):
        v[k] = alpha * v[k - 1] + rng.normal(scale=scale, size=6)
    return v


@pytest.mark.parametrize("alpha", [0.3, 0.6, 0.9])
def test_recovers_the_persistence_of_an_ar1_motion(alpha):
    factors = _testing.motion_persistence(ar1(alpha, 2000), 500)
    # 500-frame window: the least-squares estimate's standard error is ~sqrt((1 - a^2) / 500) < 0.045
    np.testing.assert_allclose(factors[-1], alpha, atol=0.12)


def test_steady_motion_is_predicted_in_full_and_an_alternating_one_not_at_all():
    steady = np.tile([1.2, 0.01, 0.0, 0.0, 0.0, 0.02], (60, 1))
    steady += np.random.default_rng(1).normal(scale=1e-4, size=steady.shape)
    factors = _testing.motion_persistence(steady, 90)
    assert factors[-1][[0, 1, 5]].min() > 0.99, factors[-1]
    alternating = np.outer((-1.0) ** np.arange(60), np.ones(6))
    np.testing.assert_array_equal(_testing.motion_persistence(alternating, 90)[-1], np.zeros(6))


def test_noisy_estimates_of_a_smooth_motion_are_shrunk_by_their_noise():
    """Estimates z = v + n of a slowly varying v (persistence ~1): the least-squares factor is the Wiener gain
    E[v v] / (E[v v] + E[n n]) per axis; a precise axis keeps ~1, an axis as noisy as its motion about half."""
    k = np.arange(3000)
    v = np.outer(np.sin(2 * np.pi * k / 300.0), np.ones(6))  # E[v^2] = 0.5
    noise = np.array([0.0, 0.05, 0.3, 0.7, 1.0, 2.0])
    z = v + np.random.default_rng(2).normal(size=v.shape) * noise
    factors = _testing.motion_persistence(z, 3000)[-1]
    wiener = 0.5 / (0.5 + noise ** 2)
    np.testing.assert_allclose(factors, wiener, atol=0.05)
    assert np.all(np.diff(factors) < 0), factors


def test_constant_velocity_until_enough_consecutive_pairs():
    motions = ar1(-0.5, 30, seed=3)  # anti-persistent: every factor well under 1 once estimated
    factors = _testing.motion_persistence(motions, 90)
    np.testing.assert_array_equal(factors[:MIN_PAIRS], np.ones((MIN_PAIRS, 6)))  # row i: after i pairs
    assert np.all(factors[MIN_PAIRS] < 1.0), factors[MIN_PAIRS]
    # a frame without a registration breaks the chain: the pairs around it are not counted
    registered = np.ones(30, dtype=bool)
    registered[5] = False
    factors = _testing.motion_persistence(motions, 90, registered.tolist())
    np.testing.assert_array_equal(factors[:MIN_PAIRS + 2], np.ones((MIN_PAIRS + 2, 6)))
    assert np.all(factors[MIN_PAIRS + 2] < 1.0)
    # window 0: off
    np.testing.assert_array_equal(_testing.motion_persistence(motions, 0), np.ones((30, 6)))


def test_one_wild_frame_or_stamp_glitch_does_not_suppress_the_prediction():
    """A single velocity 100x too large (a wrong registration) enters clipped at 3 rms; a frame whose stamp interval is
    off by more than 5x (its motion / interval is wrong by that factor) breaks the chain instead of entering. Unclipped,
    the spike alone would hold every factor near 0.1 for hundreds of frames."""
    clean = ar1(0.9, 400, seed=5)
    reference = _testing.motion_persistence(clean, 90)
    spiked = clean.copy()
    spiked[200] *= 100.0
    factors = _testing.motion_persistence(spiked, 90)
    np.testing.assert_allclose(factors[230], reference[230], atol=0.15)
    dt = np.ones(400)
    dt[250] = 1e-3  # the motion of a normal frame over a 1 ms "interval"
    factors = _testing.motion_persistence(clean, 90, dt=dt.tolist())
    for k in (250, 251, 252):  # the glitch, the interval after it (5x off the glitch's), and the restart: no pairs
        np.testing.assert_array_equal(factors[k], factors[249])
    assert not np.array_equal(factors[253], factors[249])
    np.testing.assert_allclose(factors[280], reference[280], atol=0.1)
    assert factors[280].min() > 0.6, factors[280]
    # velocities, not per-frame motions: steady motion at alternating 25 / 40 ms intervals persists in full
    intervals = np.where(np.arange(100) % 2 == 0, 0.025, 0.040)
    steady = np.outer(intervals, [0.5, 0.0, 0.0, 0.0, 0.0, 0.1])
    assert _testing.motion_persistence(steady, 90, dt=intervals.tolist())[-1][[0, 5]].min() > 0.999


def test_starting_to_move_after_standing_still_is_followed_within_a_second():
    """Standing still, the estimates are noise and the factors ~0 (the prediction: standing still). When the sensor
    starts moving (100x the noise) the clipped velocities still grow the window's rms geometrically: measured 0.57
    after 10 frames, 0.85 after 20, 0.96 after 30 (1 s at 30 Hz)."""
    z = np.random.default_rng(0).normal(scale=0.01, size=(300, 6))
    z[100:] += 1.0
    factors = _testing.motion_persistence(z, 90)
    assert factors[100].max() < 0.2, factors[100]
    assert factors[120].min() > 0.75 and factors[130].min() > 0.9, (factors[120], factors[130])


def test_non_finite_motions_and_bad_arguments():
    motions = ar1(0.5, 40, seed=4)
    motions[20] = np.nan
    motions[21, 3] = np.inf
    factors = _testing.motion_persistence(motions, 90)
    assert np.all(np.isfinite(factors)) and np.all((factors >= 0.0) & (factors <= 1.0))
    still = np.zeros((20, 6))  # an axis that never moves keeps factor 1 (nothing to scale)
    np.testing.assert_array_equal(_testing.motion_persistence(still, 90)[-1], np.ones(6))
    with pytest.raises(ValueError, match="window"):
        _testing.motion_persistence(motions, -1)
    with pytest.raises(ValueError, match="registered"):
        _testing.motion_persistence(motions, 90, [True] * 3)
    with pytest.raises(ValueError, match="dt"):
        _testing.motion_persistence(motions, 90, dt=[0.1] * 3)


def test_reset_forgets_the_persistence():
    """Through Odometry (tum_kinect at 1/100, real fr1/xyz frames): factors leave 1 after 10 velocity pairs and a
    reset starts over at constant velocity."""
    data = tum_sequence(40)
    odom = line_odom_core.Odometry(line_odom_core.load_config("tum_kinect", {"downsample": 10}))
    before = [odom.register_depth(data.depth(i), data.K, float(data.stamps[i])).stats["persistence"]
              for i in range(20)]
    assert before[11] == (1.0,) * 6 and before[12] != (1.0,) * 6, before[10:14]
    odom.reset()
    after = [odom.register_depth(data.depth(i), data.K, float(data.stamps[i])).stats["persistence"]
             for i in range(20, 40)]
    assert all(p == (1.0,) * 6 for p in after[:12]) and after[12] != (1.0,) * 6, after[10:14]


def test_motion_held_from_the_prediction_is_not_scaled_again():
    """A frame held at its prediction (here: empty depth images after 40 real fr1/xyz frames) took the scaled last
    motion; the next prediction carries that as it is, so a run of frames the lines cannot register keeps one
    constant velocity (as the held directions of docs/NODE.md promise) instead of decaying by the factors every frame."""
    data = tum_sequence(40)
    odom = line_odom_core.Odometry(line_odom_core.load_config("tum_kinect", {"downsample": 10}))
    for i in range(40):
        last = odom.register_depth(data.depth(i), data.K, float(data.stamps[i]))
    assert min(last.stats["persistence"]) < 0.5, last.stats["persistence"]
    empty = np.full(data.depth(0).shape, np.nan, dtype=np.float32)
    stamp = float(data.stamps[39])
    held = []
    for _ in range(5):
        stamp += 1.0 / 32.0  # a binary fraction: equal intervals to the bit
        res = odom.register_depth(empty, data.K, stamp)
        assert res.stats["held_directions"] == 6 and np.all(np.isfinite(res.delta))
        held.append(res.delta)
    for delta in held[1:]:
        np.testing.assert_allclose(delta, held[0], rtol=0, atol=1e-12)
    assert np.linalg.norm(held[0][:3, 3]) < np.linalg.norm(last.delta[:3, 3]) * 1.2  # scaled once (dt ratio aside)
