"""The candidate search (candidates.hpp) against a plain reference: every pair of an H-line of frame a and a V-line of
frame b (moved by the guess) that passes the angle filters and comes within the distance, or the k closest of them per
line of b. One index serves guesses in turn as the passes of a frame do: a guess that moves the segments a little
re-tests the lines listed near them, a larger one lists them again; the pairs are the reference's either way."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from line_odom_core import _testing

MIN_LINE_ANGLE_DEG = 10.0  # CandidateOptions' defaults
MAX_NORMAL_ANGLE_DEG = 30.0


def segment_distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Closest distance between the segments a (N, 6) and one segment b (6,): clamped closest points."""
    p1, d1 = a[:, :3], a[:, 3:] - a[:, :3]
    p2, d2 = b[:3], b[3:] - b[:3]
    r = p1 - p2
    aa, e = np.einsum("ij,ij->i", d1, d1), d2 @ d2
    f, c, bb = r @ d2, np.einsum("ij,ij->i", d1, r), d1 @ d2
    denom = aa * e - bb * bb
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denom > 1e-18 * aa * e, np.clip((bb * f - c * e) / denom, 0.0, 1.0), 0.0)
        t = (bb * s + f) / e
        s = np.where(t < 0.0, np.clip(-c / aa, 0.0, 1.0), np.where(t > 1.0, np.clip((bb - c) / aa, 0.0, 1.0), s))
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(p1 + d1 * s[:, None] - (p2 + d2 * t[:, None]), axis=1)


def reference_pairs(seg_a, normals_a, seg_b, normals_b, guess, max_distance, k):
    R, t = guess[:3, :3], guess[:3, 3]
    dir_a = seg_a[:, 3:] - seg_a[:, :3]
    dir_a /= np.linalg.norm(dir_a, axis=1, keepdims=True)
    known_a = np.einsum("ij,ij->i", normals_a, normals_a) > 0.25
    pairs = []
    for ib in range(len(seg_b)):
        moved = np.concatenate([R @ seg_b[ib, :3] + t, R @ seg_b[ib, 3:] + t])
        dir_b = moved[3:] - moved[:3]
        dir_b /= np.linalg.norm(dir_b)
        keep = np.abs(dir_a @ dir_b) <= np.cos(np.radians(MIN_LINE_ANGLE_DEG))
        if normals_b[ib] @ normals_b[ib] > 0.25:
            nb = R @ normals_b[ib]
            with np.errstate(divide="ignore", invalid="ignore"):
                agree = np.abs(normals_a @ nb) / (np.linalg.norm(normals_a, axis=1) * np.linalg.norm(nb))
            keep &= ~known_a | (agree >= np.cos(np.radians(MAX_NORMAL_ANGLE_DEG)))
        distance = segment_distances(seg_a, moved)
        keep &= distance <= max_distance
        ids = np.flatnonzero(keep)
        if k > 0:
            ids = ids[np.lexsort((ids, distance[ids]))][:k]
        pairs += [(int(ia), ib, float(distance[ia])) for ia in sorted(ids)]
    return pairs


def scene(rng, lines: int, extent: float):
    """H-lines (horizontal) in a street-sized box and V-lines (vertical) near them, some with surface normals."""
    centres = rng.uniform([-extent, -extent, -2.0], [extent, extent, 2.0], (lines, 3))
    heading = rng.uniform(0.0, 2.0 * np.pi, lines)
    half = rng.uniform(0.1, 2.0, lines)[:, None]
    along = np.column_stack([np.cos(heading), np.sin(heading), rng.normal(0.0, 0.05, lines)])
    seg_a = np.hstack([centres - half * along, centres + half * along])
    tilt = rng.normal(0.0, 0.1, (lines, 3))
    tilt[:, 2] = 1.0
    tilt /= np.linalg.norm(tilt, axis=1, keepdims=True)
    foot = centres + rng.normal(0.0, 0.4, (lines, 3))
    height = rng.uniform(0.1, 1.5, lines)[:, None]
    seg_b = np.hstack([foot - height * tilt, foot + height * tilt])
    normals_a = np.column_stack([-np.sin(heading), np.cos(heading), np.zeros(lines)])
    normals_b = normals_a + rng.normal(0.0, 0.3, (lines, 3))
    normals_a[rng.random(lines) < 0.3] = 0.0
    normals_b[rng.random(lines) < 0.3] = 0.0
    return seg_a, normals_a, seg_b, normals_b


def pose(rotation_deg, translation):
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(np.radians(rotation_deg)).as_matrix()
    T[:3, 3] = translation
    return T


# (guess, distance) in the order passes would ask: small steps re-test the listed lines, the jumps list them again; the
# shrinking distances of kitti_hdl64's passes re-test the lines listed at the first.
SCHEDULE = [(pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), 2.0),
            (pose([0.0, 0.0, 0.02], [0.01, -0.02, 0.0]), 2.0),
            (pose([0.0, 0.0, 0.05], [0.05, 0.01, 0.01]), 2.0),
            (pose([0.1, -0.1, 3.0], [0.8, -0.5, 0.1]), 2.0),
            (pose([0.1, -0.1, 3.01], [0.82, -0.5, 0.1]), 1.0),
            (pose([0.1, -0.1, 3.02], [0.83, -0.5, 0.1]), 0.5),
            (pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0]), 3.0)]


@pytest.mark.parametrize("lines, extent", [(300, 15.0), (1500, 35.0)], ids=["box scan", "grid"])
@pytest.mark.parametrize("k", [0, 3])
def test_pairs_match_the_reference_for_every_guess_in_turn(lines, extent, k):
    rng = np.random.default_rng(lines + k)
    seg_a, normals_a, seg_b, normals_b = scene(rng, lines, extent)
    guesses, distances = zip(*SCHEDULE)
    found = _testing.candidate_pairs(seg_a, normals_a, seg_b, normals_b, list(guesses), list(distances), k)
    for (guess, distance), pairs in zip(SCHEDULE, found):
        expected = reference_pairs(seg_a, normals_a, seg_b, normals_b, guess, distance, k)
        assert len(expected) > lines // 4  # the scenes are dense enough to give many lines partners
        assert [(ia, ib) for ia, ib, _ in pairs] == [(ia, ib) for ia, ib, _ in expected]
        np.testing.assert_allclose([d for *_, d in pairs], [d for *_, d in expected], rtol=0, atol=1e-9)


@pytest.mark.parametrize("lines, extent", [(300, 15.0), (1500, 35.0)], ids=["box scan", "grid"])
@pytest.mark.parametrize("k", [0, 3])
def test_a_subset_of_frame_a_gives_the_pairs_of_that_subset_alone(lines, extent, k):
    """The first lines of frame a (a registration window's newest scan, merged ahead of older ones) searched on the
    index of all of them, its listings shared with the searches before: the pairs of an index of those lines alone."""
    rng = np.random.default_rng(lines + k + 1)
    seg_a, normals_a, seg_b, normals_b = scene(rng, lines, extent)
    taken = lines // 3
    guesses, distances = zip(*SCHEDULE)
    everything = _testing.candidate_pairs(seg_a, normals_a, seg_b, normals_b, list(guesses), list(distances), k)
    found = _testing.candidate_pairs(seg_a, normals_a, seg_b, normals_b, list(guesses), list(distances), k, taken)
    for (guess, distance), pairs, all_pairs in zip(SCHEDULE, found, everything):
        expected = reference_pairs(seg_a[:taken], normals_a[:taken], seg_b, normals_b, guess, distance, k)
        assert len(expected) > taken // 4 and len(all_pairs) > len(expected)
        assert [(ia, ib) for ia, ib, _ in pairs] == [(ia, ib) for ia, ib, _ in expected]
