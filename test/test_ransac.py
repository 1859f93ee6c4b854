"""The RANSAC loop itself (line_odom_core/cpp/registration/ransac.hpp) through two small estimators with known
answers (line_odom_core._testing): a 2D line fit (generic form) and a 2D translation from two data types and two
solvers (hybrid form)."""
import numpy as np
import pytest

from line_odom_core import _testing


def line_points(rng, n_in, n_out, *, slope=0.5, offset=1.0, noise=0.01, box=5.0):
    x = rng.uniform(-box, box, n_in)
    inl = np.c_[x, slope * x + offset + rng.normal(scale=noise, size=n_in)]
    out = rng.uniform(-box, box, size=(n_out, 2))
    pts = np.r_[inl, out]
    truth = np.r_[np.zeros(n_in, bool) | True, np.zeros(n_out, bool)]
    perm = rng.permutation(len(pts))
    return pts[perm], truth[perm]


def slope_offset(line):
    a, b, c = line
    return -a / b, -c / b


def test_line_fit_with_half_outliers():
    rng = np.random.default_rng(0)
    pts, truth = line_points(rng, 150, 150)
    line, st = _testing.ransac_fit_line_2d(pts, 0.03, seed=3)
    assert st["success"]
    assert np.hypot(line[0], line[1]) == pytest.approx(1.0)
    slope, offset = slope_offset(line)
    assert slope == pytest.approx(0.5, abs=3e-3) and offset == pytest.approx(1.0, abs=3e-3)
    residual = np.abs(pts @ line[:2] + line[2])
    assert st["inliers"] == np.sum(residual < 0.03)
    assert np.sum(truth & (residual < 0.03)) >= 0.95 * truth.sum()
    assert st["inlier_fraction"][0] == pytest.approx(st["inliers"] / len(pts))
    assert 1 <= st["iterations"] < 1000 and st["best_iteration"] < st["iterations"]


def test_weights_decide_between_two_lines():
    rng = np.random.default_rng(1)
    a, _ = line_points(rng, 60, 0, slope=0.5, offset=1.0)
    b, _ = line_points(rng, 100, 0, slope=-2.0, offset=0.0)
    pts = np.r_[a, b]
    weights = np.r_[np.ones(60), np.full(100, 0.1)]
    unweighted, _ = _testing.ransac_fit_line_2d(pts, 0.03, seed=0, min_iterations=200)
    weighted, st = _testing.ransac_fit_line_2d(pts, 0.03, weights=weights, seed=0, min_iterations=200)
    assert slope_offset(unweighted)[0] == pytest.approx(-2.0, abs=0.01)
    assert slope_offset(weighted)[0] == pytest.approx(0.5, abs=0.01)
    # score is the weighted count: the 60 points of line a plus whatever few of b cross it within 3 cm
    assert 60.0 <= st["score"] < 61.0


def test_same_seed_same_result_other_seed_other_samples():
    rng = np.random.default_rng(2)
    pts, _ = line_points(rng, 80, 120)
    runs = [_testing.ransac_fit_line_2d(pts, 0.03, seed=11) for _ in range(3)]
    for line, st in runs[1:]:
        np.testing.assert_array_equal(line, runs[0][0])
        assert st == runs[0][1]
    others = [_testing.ransac_fit_line_2d(pts, 0.03, seed=s)[1] for s in range(12, 20)]
    assert any((o["iterations"], o["best_iteration"]) != (runs[0][1]["iterations"], runs[0][1]["best_iteration"])
               for o in others)


@pytest.mark.parametrize("n_in,n_out", [(180, 20), (100, 100), (60, 140)])
def test_stops_by_confidence(n_in, n_out):
    rng = np.random.default_rng(n_in)
    pts, _ = line_points(rng, n_in, n_out, noise=0.002)
    confidence = 0.99
    _, st = _testing.ransac_fit_line_2d(pts, 0.01, seed=5, confidence=confidence, max_iterations=100000)
    eps = st["inlier_fraction"][0]
    assert eps == pytest.approx(n_in / (n_in + n_out), abs=0.03)
    # stopped once P(no all-inlier pair yet) < 1 - confidence under the inlier fraction found; the fraction
    # only grows, so at least the samples that the final fraction asks for were drawn
    needed = np.log(1 - confidence) / np.log(1 - eps ** 2)
    assert needed - 1 <= st["iterations"] <= 10 * needed + 10


def test_max_and_min_iterations():
    rng = np.random.default_rng(4)
    noise = rng.uniform(-5, 5, size=(300, 2))
    _, st = _testing.ransac_fit_line_2d(noise, 0.001, seed=1, max_iterations=37)
    assert st["iterations"] == 37
    exact = np.c_[np.arange(50.0), 2 * np.arange(50.0)]
    _, st = _testing.ransac_fit_line_2d(exact, 0.001, seed=1, min_iterations=25)
    assert st["iterations"] == 25 and st["inliers"] == 50


def test_nothing_to_sample():
    line, st = _testing.ransac_fit_line_2d(np.array([[1.0, 2.0]]), 0.01)
    assert not st["success"] and st["iterations"] == 0
    assert np.all(np.isfinite(line))


def test_local_optimisation_refines_the_best_model():
    rng = np.random.default_rng(5)
    errors = {True: [], False: []}
    for trial in range(20):
        pts, _ = line_points(rng, 300, 100, noise=0.02)
        for lo in (True, False):
            line, st = _testing.ransac_fit_line_2d(pts, 0.06, seed=trial, local_optimisation=lo)
            assert (st["refinements"] > 0) == lo
            slope, offset = slope_offset(line)
            errors[lo].append(abs(slope - 0.5) + abs(offset - 1.0))
    assert np.mean(errors[True]) < 0.5 * np.mean(errors[False])


def translation_data(rng, t, n_pairs, pair_outliers, n_proj, proj_outliers, noise=0.005):
    pb = rng.uniform(-10, 10, size=(n_pairs, 2))
    pa = pb + t + rng.normal(scale=noise, size=(n_pairs, 2))
    bad = rng.uniform(size=n_pairs) < pair_outliers
    pa[bad] = rng.uniform(-10, 10, size=(bad.sum(), 2))
    ang = rng.uniform(0, np.pi, n_proj)
    u = np.c_[np.cos(ang), np.sin(ang)]
    o = u @ t + rng.normal(scale=noise, size=n_proj)
    bad = rng.uniform(size=n_proj) < proj_outliers
    o[bad] = rng.uniform(-10, 10, bad.sum())
    return pa, pb, u, o


def test_hybrid_prefers_the_solver_whose_data_are_clean():
    rng = np.random.default_rng(6)
    t = np.array([1.5, -0.7])
    # point pairs all wrong, projections clean: only the two-projection solver can win
    pa, pb, u, o = translation_data(rng, t, 100, 1.0, 100, 0.1)
    est, st = _testing.ransac_translation_2d(pa, pb, u, o, 0.03, seed=1)
    assert np.linalg.norm(est - t) < 0.02
    assert st["best_solver"] == 1
    assert st["solver_iterations"][1] > st["solver_iterations"][0]
    assert st["inlier_fraction"][1] > 0.85 and st["inlier_fraction"][0] < 0.05
    # point pairs mostly right, projections mostly wrong: whichever solver wins first, the one-pair solver
    # keeps a share, wins, and its high all-inlier probability ends the search early (two projections alone:
    # P = 0.2^2, about 170 samples for 0.999)
    for seed in range(5):
        pa, pb, u, o = translation_data(rng, t, 100, 0.2, 100, 0.8)
        est, st = _testing.ransac_translation_2d(pa, pb, u, o, 0.03, seed=seed)
        assert np.linalg.norm(est - t) < 0.02
        assert st["inlier_fraction"][0] > 0.7
        assert st["iterations"] < 40


def test_hybrid_skips_a_solver_without_data():
    rng = np.random.default_rng(7)
    t = np.array([-3.0, 2.0])
    pa, pb, _, _ = translation_data(rng, t, 50, 0.3, 0, 0.0)
    est, st = _testing.ransac_translation_2d(pa, pb, np.zeros((1, 2)), np.zeros(1), 0.03, seed=2)
    assert st["solver_iterations"][1] == 0 and st["best_solver"] == 0
    assert np.linalg.norm(est - t) < 0.02
    _, st = _testing.ransac_translation_2d(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((1, 2)), np.zeros(1), 0.03)
    assert not st["success"] and st["iterations"] == 0


def test_hook_rejects_bad_shapes():
    with pytest.raises(ValueError, match="points"):
        _testing.ransac_fit_line_2d(np.zeros((5, 3)), 0.1)
    with pytest.raises(ValueError, match="weights"):
        _testing.ransac_fit_line_2d(np.zeros((5, 2)), 0.1, weights=np.ones(4))
