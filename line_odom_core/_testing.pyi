"""Type stubs of line_odom_core._testing (pybind11): hooks for the tests and bench/solvers.py into engine parts that
have no entry of their own in _core. The node never imports it."""
from typing import Any, Sequence

import numpy as np
import numpy.typing as npt

def benchmark_solver(solver: str, instances: int = 1000, repetitions: int = 5, seed: int = 0, *,
                     method: str = "gauss_newton", max_iterations: int = 30000, tolerance: float = 1e-12,
                     found_tolerance: float = 1e-6, guess_rotation_deg: float = 5.0, guess_translation: float = 0.5,
                     max_translation: float = 2.0, scene_radius: float = 10.0, chunk: int = 0) -> dict[str, Any]:
    """C++ timing loop over seeded noise-free instances of "1l2p", "3l1p" or "7l", timed in chunks of `chunk`
    consecutive calls (0: auto). Keys: solver, method, instances, repetitions, median_us, p90_us, min_us, mean_us,
    chunk, solutions_per_call, found_rate, no_solution_rate, median_error, p99_error, mean_iterations."""

# The generic and the hybrid RANSAC (registration/ransac.hpp) on two small estimators with known answers
# (testing/ransac_examples.hpp); stats: success, iterations, models, refinements, best_solver, best_iteration, score,
# inliers, inlier_fraction, solver_iterations, solver_wins.
def ransac_fit_line_2d(points: npt.ArrayLike, threshold: float, *, weights: npt.ArrayLike | None = None,
                       max_iterations: int = 1000, min_iterations: int = 0, confidence: float = 0.999,
                       seed: int = 0, local_optimisation: bool = True
                       ) -> tuple[npt.NDArray[np.float64], dict[str, Any]]: ...  # line (a, b, c), a^2 + b^2 = 1
def ransac_translation_2d(points_a: npt.ArrayLike, points_b: npt.ArrayLike, directions: npt.ArrayLike,
                          projections: npt.ArrayLike, threshold: float, *, max_iterations: int = 1000,
                          min_iterations: int = 0, confidence: float = 0.999, seed: int = 0
                          ) -> tuple[npt.NDArray[np.float64], dict[str, Any]]: ...  # translation (2,)

def motion_persistence(motions: npt.ArrayLike, window: int, registered: Sequence[bool] | None = None,
                       dt: Sequence[float] | None = None
                       ) -> npt.NDArray[np.float64]: ...  # (N, 6) factors after each motion (motion_persistence.hpp)
def odometry_config_defaults() -> dict[str, bool | int | float | str]: ...  # OdometryConfig{}'s values, by name

# The local point map's nearest-point lookup (registration/voxel_points.hpp) over points (N, 3, world frame) in cubes of
# `voxel` metres, added scan by scan (scan_of: each point's scan, in consecutive runs; sensor_positions (S, 3): where
# each scan's sensor stood; none: one scan at the origin), a full cube's points from within `same_place` metres of
# another scan's place giving way (negative: never): for each query (M, 3), the map point returned within max_distance
# (NaN rows where none) and its voxel's index (-1 where none).
def voxel_map_nearest(points: npt.ArrayLike, voxel: float, max_points_per_voxel: int, queries: npt.ArrayLike,
                      max_distance: float, *, scan_of: Sequence[int] | None = None,
                      sensor_positions: npt.ArrayLike | None = None,
                      same_place: float = -1.0) -> tuple[npt.NDArray[np.float64], list[int]]: ...

# The point map's alignment (point_alignment.hpp) of scan (N, 3) from initial_pose (4x4) to a map of map_points (M, 3)
# in cubes of `voxel` metres, measured over the plane ground (a, b, c, d) or None, its kernel from sigma: the 4x4 pose
# it ends at.
def point_map_alignment(map_points: npt.ArrayLike, ground: npt.ArrayLike | None, voxel: float, scan: npt.ArrayLike,
                        initial_pose: npt.ArrayLike, sigma: float) -> npt.NDArray[np.float64]: ...

# The candidate search (candidates.hpp) of the lines of frame a (segments (N, 6), normals (N, 3), 0 where unknown)
# against those of frame b moved by each guess (4x4) within its distance, in turn on one index: per guess the pairs
# (index in a, index in b, segment distance). taken_a >= 0: only the first taken_a lines of a are partners.
def candidate_pairs(segments_a: npt.ArrayLike, normals_a: npt.ArrayLike, segments_b: npt.ArrayLike,
                    normals_b: npt.ArrayLike, guesses: list[npt.ArrayLike], max_distances: list[float],
                    max_pairs_per_line: int, taken_a: int = -1) -> list[list[tuple[int, int, float]]]: ...
