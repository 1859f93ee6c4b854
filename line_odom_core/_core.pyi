"""Type stubs of the C++ engine module line_odom_core._core (pybind11)."""
from typing import Any

import numpy as np
import numpy.typing as npt

__version__: str

def build_info() -> dict[str, Any]: ...

# ---- solvers and motion estimation ----

MAX_DIHEDRAL_DIFFERENCE_1L2P: float

def solve_1l2p(line_a: npt.ArrayLike, line_b: npt.ArrayLike, planes_a: npt.ArrayLike, planes_b: npt.ArrayLike,
               *, max_dihedral_difference: float = ...) -> list[npt.NDArray[np.float64]]:
    """1L2P (paper 5.1): line_a (6,) meets T line_b (6,); planes_a (2,4) = T planes_b (2,4). 0 or 1 poses (4,4)."""

def solve_3l1p(lines_a: npt.ArrayLike, lines_b: npt.ArrayLike, plane_a: npt.ArrayLike,
               plane_b: npt.ArrayLike) -> list[npt.NDArray[np.float64]]:
    """3L1P (paper 5.2): lines_a (3,6) meet T lines_b (3,6); plane_a (4,) = T plane_b (4,). 0 to 4 poses (4,4)."""

def solve_7l(segments_a: npt.ArrayLike, segments_b: npt.ArrayLike, init: npt.ArrayLike | None = None, *,
             method: str = "gauss_newton", max_iterations: int = 30000, tolerance: float = 1e-12,
             max_residual: float = ...) -> list[npt.NDArray[np.float64]]:
    """7L (paper 4): segments_a (7,2,3) meet T segments_b (7,2,3), from init (4,4) (None = identity).
    method: "gauss_newton" (default) or "alternating_projection" (the paper's). 0 or 1 poses (4,4)."""

def estimate_motion(lines_a: npt.ArrayLike, lines_b: npt.ArrayLike, planes_a: npt.ArrayLike | None,
                    planes_b: npt.ArrayLike | None, *, segments_a: npt.ArrayLike | None = None,
                    segments_b: npt.ArrayLike | None = None, weights: npt.ArrayLike | None = None,
                    clusters: npt.ArrayLike | None = None, init: npt.ArrayLike | None = None,
                    options: dict[str, Any] = {}) -> tuple[npt.NDArray[np.float64], dict[str, Any]]:
    """Hybrid RANSAC over {7L, 3L1P, 1L2P} + robust refinement (paper 6.3). Row i of lines_a (N,6) is a candidate
    intersection with row i of lines_b; planes (M,4) likewise; segments (N,2,3) (7L; built from the lines when
    absent); weights (N,) >= 0; clusters (N,) int in {-1,0,1,2}; init (4,4) (None = identity).
    options: by name, as estimate_motion_options() lists them (solver, max_iterations, inlier_threshold, seed, ...).
    Returns (T_ab (4,4), stats); T_ab = init when stats["success"] is False. stats keys: success, inliers,
    inlier_weight, plane_inliers, iterations, models, solver_counts (new-best hypotheses per solver),
    solver_iterations (samples per solver), best_solver (str | None), covariance (6,6; x y z rx ry rz; left
    perturbation), residual_rms, degenerate, condition, perturbed_inlier_weight (chance support of the estimate
    pushed 20 thresholds along 8 diagonals; success needs inlier_weight >= min_inlier_contrast * it
    + 3 sqrt(it)), dropped_line_pairs, dropped_plane_pairs,
    line_inlier_mask (N,), plane_inlier_mask (M,)."""

# ---- scan features ----

# Range image dicts: points (H, W, 3) float64 with NaN holes, valid (H, W) bool, source_index (H, W) int32
# (organize_points only), stats (input/kept/invalid/out_of_range/outside_rows/cell_collisions, row_method).
def organize_points(points: npt.ArrayLike, ring: npt.ArrayLike | None = None, sensor: str = "hdl64",
                    min_range: float = 0.0, max_range: float = 1e9, downsample: int = 1,
                    downsample_while_organizing: bool = False) -> dict[str, Any]: ...
def organize_depth(depth: npt.ArrayLike, K: npt.ArrayLike, min_depth: float = 0.0, max_depth: float = 1e9,
                   downsample: int = 1, downsample_while_organizing: bool = False) -> dict[str, Any]: ...
# {"h_lines"/"v_lines": {segments (N,2,3), plucker (N,6), normals (N,3), cluster, rms, support, scan_index,
#  first, last, normal_support, plane}, "planes": {planes (P,4) [n, delta], centroids (P,3), rms, support},
#  "cluster_directions" (3,3), "stats": {...}}
def extract_features(range_image: npt.ArrayLike, config: dict[str, float | int | bool] | None = None, *,
                     threads: int = 1) -> dict[str, Any]: ...  # config over the defaults; presets: line_odom_core's
def feature_config() -> dict[str, float | int | bool]: ...  # lines.*, normals.*, planes.* with their defaults
def sensor_presets() -> list[str]: ...

# ---- odometry pipeline ----

class FrameResult:
    """One registered frame, as returned by Odometry.register_*.

    stats keys:
      solver: str             "7L", "3L1P" or "1L2P" (solver of the winning hypothesis); "none" on the first
                              frame after construction/reset; "refine" when the refined guess won; "points" when the
                              lines registered nothing and the point map's alignment was taken; "prediction" when the
                              motion model's prediction was held
      points: int             valid range-image cells after downsampling
      h_lines, v_lines: int   lines fitted along rows / columns
      fit_step: int           the lines were fitted on every fit_step-th row and column (line_selection.hpp)
      line_step: int          of those, the lines of every line_step-th row and column were registered
                              (registration.max_lines; 1 = all)
      registered_lines: int   of those lines, how many entered the registration
      planes: int             planes fitted
      candidates: int         candidate line-intersection pairs (last pass)
      plane_candidates: int   candidate plane pairs (last pass)
      inliers: int            inlier line pairs of the accepted estimate
      plane_inliers: int      inlier plane pairs of the accepted estimate
      inlier_weight: float    weighted inlier count (weights = inverse normal-cluster size, mean 1)
      residual_rms: float     rms line-to-line distance of the inliers after refinement (m)
      iterations: int         RANSAC hypotheses over all passes
      passes: int             passes that produced an accepted estimate (of registration.passes)
      registered: bool        an estimate was accepted for this frame (the first frame counts as registered)
      degenerate: bool        the prediction was held (in full, or along held_directions) and the covariance
                              inflated there
      held_directions: int    0 registered in full; 1-5 a partial estimate (registration.partial_updates): that many
                              directions of the motion the lines do not observe come from the prediction, the rest
                              from the lines; 6 the prediction held in full
      persistence: tuple      6 floats (x y z rx ry rz): the share of the last motion this frame's prediction
                              carried (registration.persistence_window; 1 = constant velocity)
      prediction: str         where this frame's prediction came from: "constant_velocity", "guess" (the caller's
                              motion guess), "standing_still" (no velocity yet, or constant_velocity off), "none"
                              (first frame); with a rotation_guess "constant_velocity+imu" / "standing_still+imu"
      failure: str            why, when degenerate ("" otherwise)
      unmeasured_directions: int  directions of the velocity no frame has measured since the first motion was held
                              at standing still (after a start, reset or stamp gap where the scene did not observe
                              the motion): 0 normally; while > 0, each frame searches them (the prediction holds them
                              at zero, the motion prior does not pull towards it)
      recovered: bool         this frame's motion was found by that search
      turn_searched: bool     the registration failed, held a direction with a rotation in it or kept less than a
                              third of the last frame's inlier weight: the heading was scanned about the ground's up
                              axis and registered from the best-supported one
      turn_recovered: bool    ... and that motion replaced the frame's: it observes every direction and the candidates
                              picked near it support it 1.5 times as much
      window_scans: int       previous scans this frame was registered against: registration.window when the last
                              scan alone observed every direction of that motion, else 1 (0 on the first frame)
      deskewed: bool          the points had times and were moved to the stamp at the predicted velocity
      previous_deskewed_again: bool  ... and the previous scan, deskewed at another velocity, was again at this one
                              (its features moved), so that both scans are corrected alike
      deskewed_again: int     times the sweep was deskewed again at the motion registered for it and registered again
                              (sensor.deskew_iterations)
      points_refined: bool    the point-to-plane refinement (points.*) moved the lines' estimate: this scan's voxel
                              means against the previous scan's voxel planes, jointly with the lines' estimate
      point_matches: int      ... this many voxel means had a planar partner
      observability: tuple    6 floats (x y z rx ry rz): McNemar's z of the lines meeting under the motion against
                              the motion pushed validation.tolerance either way (0 where not tested)
      unobserved: int         bit k: direction k of the motion not confirmed (the point map's alignment differs by
                              more than validation.tolerance where it resolves the direction; without it, and at a
                              first motion, McNemar's z under validation.significance): held at the alignment, flagged
      points_aligned: bool    this scan's points were aligned to the point map (point_map.*)
      point_map_matches: int  ... this many of them found a map point within the alignment's reach
      map_entry: str          where the scan entered the point map: "pose" (its registered pose), "points" (its motion
                              partly held at the prediction: where its points put it), "none" (stayed out: the map
                              does not judge the next frame)
      ms: dict[str, float]    milliseconds per stage, the keys below

    stats["ms"] keys:
      organize                organizing the scan into a range image (the deskew before the registration included)
      deskew                  correcting both scans' sweeps (before the registration: part of organize; after it,
                              at the registered motion: besides the other stages)
      downsample              keeping every downsample-th row and column
      features                lines, normals and planes, of which:
      lines                   ... fitting the lines
      normals                 ... the lines' normals and their clusters
      planes                  ... fitting the planes
      candidates              candidate line and plane pairs
      ransac                  the hybrid RANSAC and its refinement
      points                  the point-to-plane refinement and this scan's voxels
      validation              the lines' observability, aligning the points to the point map, adding this scan to it
      total                   the whole frame
    """

    stamp: float
    @property
    def pose(self) -> npt.NDArray[np.float64]: ...  # (4, 4) T_world_sensor
    @property
    def delta(self) -> npt.NDArray[np.float64]: ...  # (4, 4) T_prev_curr
    covariance: npt.NDArray[np.float64]  # (6, 6) of delta, order x y z rx ry rz
    @property
    def stats(self) -> dict[str, Any]: ...

class Odometry:
    """Stateful frame-to-frame odometry. settings: dotted engine settings (see line_odom_core.config_schema());
    unknown names or wrong types raise ValueError. All register_* calls release the GIL."""

    def __init__(self, settings: dict[str, bool | int | float | str]) -> None: ...
    # guess: (4, 4) T_prev_curr of the sensor from another source (wheel odometry, IMU), or None
    # rotation_guess: (3, 3) R_prev_curr of the sensor (a gyro's), or None; replaces only the prediction's rotation
    def register_points(self, xyz: npt.NDArray[np.floating], stamp: float,
                        ring: npt.NDArray[np.int32] | None = None,
                        guess: npt.NDArray[np.float64] | None = None,
                        rotation_guess: npt.NDArray[np.float64] | None = None,
                        time: npt.NDArray[np.float64] | None = None,
                        sweep_rate: npt.NDArray[np.float64] | None = None) -> FrameResult: ...  # xyz (N, k>=3), time (N,)
    def register_organized(self, xyz: npt.NDArray[np.floating], stamp: float,
                           guess: npt.NDArray[np.float64] | None = None,
                           rotation_guess: npt.NDArray[np.float64] | None = None,
                           time: npt.NDArray[np.float64] | None = None,
                           sweep_rate: npt.NDArray[np.float64] | None = None) -> FrameResult: ...  # (H, W, k>=3), (H, W)
    def register_depth(self, depth: npt.NDArray[np.float32], K: npt.NDArray[np.float64],
                       stamp: float, guess: npt.NDArray[np.float64] | None = None,
                       rotation_guess: npt.NDArray[np.float64] | None = None) -> FrameResult: ...
    def downsampled_points(self, xyz: npt.NDArray[np.floating],
                           ring: npt.NDArray[np.int32] | None = None) -> npt.NDArray[np.float64]: ...
    def sensor_fit(self, xyz: npt.NDArray[np.floating],
                   ring: npt.NDArray[np.int32] | None = None) -> dict[str, str | int | float]: ...
    def reset(self, pose: npt.NDArray[np.float64]) -> None: ...
    def pose(self) -> npt.NDArray[np.float64]: ...
    def last_lines(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]: ...
    def keep_points(self, keep: bool) -> None: ...
    def last_points(self) -> npt.NDArray[np.float64]: ...
    def frames(self) -> int: ...
    def settings(self) -> dict[str, bool | int | float | str]: ...

def reads_in_place(xyz: npt.NDArray[np.floating]) -> bool: ...  # register_points / register_organized copy nothing

# Per-frame rotation conversions of the Python side (Eigen's).
def rotation_vector(R: npt.ArrayLike) -> npt.NDArray[np.float64]: ...  # (3,) axis * angle, angle in [0, pi]
def quaternion_xyzw(R: npt.ArrayLike) -> npt.NDArray[np.float64]: ...  # (4,) unit quaternion x, y, z, w with w >= 0

# ---- settings (odometry/engine_settings.cpp) ----

# One dict per setting: name, type ("bool", "int", "float", "str"), default, min, max (None: unbounded), min_open,
# max_open, zero_is_off, choices, unit, description, runtime, expected (what it accepts, as its errors say it).
def settings_schema() -> list[dict[str, Any]]: ...
def estimate_motion_options() -> list[dict[str, Any]]: ...
def check_setting(name: str, value: bool | int | float | str) -> bool | int | float | str: ...
