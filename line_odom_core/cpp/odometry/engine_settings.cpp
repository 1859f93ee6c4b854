// The engine's settings: name, member, accepted values, unit, description. Defaults are the structs' own.
// Ranges: number("name", &Struct::member, "[min, max]" | "(min, max]" | "> min" | "0 (off) or [min, max]", unit, ...).
#include "odometry/engine_settings.hpp"

namespace line_odom {

namespace {

SettingsTable<SensorOptions> sensor_settings() {
  return {"engine setting", {
      choice("model", &SensorOptions::model, {"hdl64", "kitti", "vlp16", "os128", "uniform"},
             "how unorganized clouds map onto rows (beams) and columns (azimuth): hdl64 (= kitti), vlp16, os128, or "
             "uniform (sensor.rows beams evenly spaced between the elevation limits); organized clouds and depth "
             "images ignore it"),
      number("rows", &SensorOptions::rows, "[0, 1024]", "", "beams of a uniform sensor model (0 = the preset's)"),
      number("cols", &SensorOptions::cols, "[0, 65536]", "", "azimuth bins of the range image (0 = the preset's)"),
      number("max_elevation_deg", &SensorOptions::max_elevation_deg, "[-90, 90]", "deg",
             "uniform model: elevation of the top beam"),
      number("min_elevation_deg", &SensorOptions::min_elevation_deg, "[-90, 90]", "deg",
             "uniform model: elevation of the bottom beam"),
      number("min_range", &SensorOptions::limits, &RangeLimits::min_range, "[0, 1e6]", "m",
             "closer points are holes (depth cameras: depth z)"),
      number("max_range", &SensorOptions::limits, &RangeLimits::max_range, "[0, 1e9]", "m",
             "farther points are holes"),
      flag("deskew", &SensorOptions::deskew,
           "points given with their times (a PointCloud2's t/time/timestamp field) are moved into the sensor frame at "
           "the stamp at the predicted velocity (motion compensation of the sweep); false: used as measured"),
      number("deskew_tolerance", &SensorOptions::deskew_tolerance, "[0, 10]", "m",
             "the previous scan is deskewed again at the current velocity when the two corrections put a point 20 m "
             "away further apart than this, so both scans of a registration are corrected alike"),
      number("deskew_trend", &SensorOptions::deskew_trend, "0 (off) or [3, 20]", "frames",
             "a sweep is corrected at the pair's velocity plus how much faster it moves than the previous sweep: the "
             "slope of the last n frames' velocities registered in full (a flagged frame starts it afresh; 0: off, both "
             "scans of a pair at one velocity)"),
      number("deskew_iterations", &SensorOptions::deskew_iterations, "[0, 10]", "",
             "once registered, a sweep whose registered velocity moves a point 20 m away further than "
             "deskew_tolerance from where the prediction's did is deskewed again at it (its features and the "
             "previous scan's moved) and registered again from the estimate, at most this many times; 0: at the "
             "prediction only"),
  }};
}

// Line fitting on rows (H-lines) and columns (V-lines), paper §6.2.
SettingsTable<LineFitConfig> line_settings() {
  return {"feature parameter", {
      number("min_points_h", &LineFitConfig::min_points_h, "[2, 100000]", "", "inlier points an H-line (row) needs"),
      number("min_points_v", &LineFitConfig::min_points_v, "[2, 100000]", "",
             "inlier points a V-line (column) needs (few rows when downsampled)"),
      number("min_length", &LineFitConfig::min_length, "[0, 1000]", "m", "shortest line between its end points"),
      number("split_distance", &LineFitConfig::split_distance, "(0, 10]", "m",
             "largest point-to-line distance inside one line (at range 0; grows with range)"),
      number("max_rms", &LineFitConfig::max_rms, "(0, 10]", "m",
             "largest rms of a line fit (at range 0; grows with range)"),
      number("threshold_per_m", &LineFitConfig::threshold_per_m, "[0, 10]", "1/m",
             "line thresholds scale by 1 + a r + b r^2: a"),
      number("threshold_per_m2", &LineFitConfig::threshold_per_m2, "[0, 100]", "1/m^2",
             "line thresholds scale by 1 + a r + b r^2: b"),
      number("max_gap", &LineFitConfig::max_gap, "[0, 1000]", "cells", "missing cells bridged inside one line"),
      // 90 deg would make every step along a scan line a depth jump.
      number("min_incidence_deg", &LineFitConfig::min_incidence_deg, "[0, 90)", "deg",
             "steps closer than this to the viewing ray are depth jumps"),
      number("trim_sigmas", &LineFitConfig::trim_sigmas, "(0, 100]", "",
             "line end points farther than this many rms from the line are trimmed"),
      number("max_outliers", &LineFitConfig::max_outliers, "[0, 1000]", "",
             "stray points skipped between two collinear pieces"),
  }};
}

// Line normals from H/V crossings and their 3 clusters, paper §6.2-6.3.
SettingsTable<NormalConfig> normal_settings() {
  return {"feature parameter", {
      number("min_crossing_angle_deg", &NormalConfig::min_crossing_angle_deg, "[0, 90)", "deg",
             "flatter H/V crossings give no normal"),
      number("max_deviation_deg", &NormalConfig::max_deviation_deg, "(0, 90]", "deg",
             "crossings farther than this from a line's mean normal are outliers"),
      number("min_crossings", &NormalConfig::min_crossings, "[1, 100000]", "",
             "agreeing crossings a line needs for a normal"),
      number("min_agreement", &NormalConfig::min_agreement, "[0, 1]", "",
             "fraction of a line's crossings that must agree"),
      number("vote_angle_deg", &NormalConfig::vote_angle_deg, "(0, 90)", "deg", "radius of a cluster-direction vote"),
      number("min_separation_deg", &NormalConfig::min_separation_deg, "(0, 90]", "deg",
             "least angle between cluster directions"),
      number("max_cluster_angle_deg", &NormalConfig::max_cluster_angle_deg, "(0, 90]", "deg",
             "normals farther than this from every direction stay unclustered"),
      number("min_cluster_fraction", &NormalConfig::min_cluster_fraction, "[0, 1]", "",
             "votes a direction needs, as a fraction of all normals"),
      number("end_crossing_weight", &NormalConfig::end_crossing_weight, "[0, 1]", "",
             "weight of an H/V crossing at a line's end (corners join lines of two surfaces there)"),
  }};
}

// Plane fitting, paper §6.2.
SettingsTable<PlaneFitConfig> plane_settings() {
  return {"feature parameter", {
      flag("enabled", &PlaneFitConfig::enabled, "fit planes (needed by the 3L1P and 1L2P solvers)"),
      number("max_distance", &PlaneFitConfig::max_distance, "(0, 10]", "m",
             "line end points within this of the plane join it (at range 0)"),
      // 0 deg would admit no line, 90 deg every line whatever its normal.
      number("max_normal_angle_deg", &PlaneFitConfig::max_normal_angle_deg, "(0, 90)", "deg",
             "line normal vs plane normal"),
      number("min_points", &PlaneFitConfig::min_points, "[3, 10000000]", "", "range-image points a plane needs"),
      number("min_lines", &PlaneFitConfig::min_lines, "[2, 100000]", "", "H- and V-lines a plane needs"),
      number("min_extent", &PlaneFitConfig::min_extent, "[0, 1000]", "m",
             "shorter side of the plane's equal-moment rectangle"),
      number("max_rms", &PlaneFitConfig::max_rms, "(0, 10]", "m", "point-to-plane rms"),
      number("max_planes", &PlaneFitConfig::max_planes, "[0, 10000]", "", "keep the largest this many planes"),
  }};
}

// Candidate pairs under the motion guess, paper §6.3.
SettingsTable<CandidateOptions> candidate_settings() {
  return {"engine setting", {
      number("max_distance", &CandidateOptions::max_distance, "[0.001, 100]", "m",
             "line pairs whose segments come within this distance under the motion guess are candidate "
             "intersections (paper: 2 m on KITTI)"),
      number("min_line_angle_deg", &CandidateOptions::min_line_angle_deg, "[0, 89]", "deg",
             "skip candidate pairs of lines closer to parallel than this"),
      number("max_normal_angle_deg", &CandidateOptions::max_normal_angle_deg, "[0, 90]", "deg",
             "when both lines have a surface normal, the normals must agree within this angle; 90 disables"),
      number("plane_max_angle_deg", &CandidateOptions::plane_max_angle_deg, "[0, 90]", "deg",
             "candidate plane pairs: normals within this angle under the guess (paper: 20)"),
      number("plane_max_distance", &CandidateOptions::plane_max_distance, "[0.001, 100]", "m",
             "candidate plane pairs: centroid-to-other-plane distance under the guess"),
      number("max_pairs_per_line", &CandidateOptions::max_pairs_per_line, "[0, 100000]", "",
             "keep only the k closest partners of each line (0 = all)"),
  }};
}

// Hybrid RANSAC and refinement (paper §6.3): what a scan registration takes from the user.
SettingsTable<MotionOptions> ransac_settings() {
  return {"engine setting", {
      choice("solver", &MotionOptions::solver,
             {{"auto", SolverMode::kAuto}, {"7L", SolverMode::k7L}, {"3L1P", SolverMode::k3L1P},
              {"1L2P", SolverMode::k1L2P}},
             "minimal solver: auto (hybrid over 7L, 3L1P, 1L2P), 7L, 3L1P or 1L2P"),
      number("max_iterations", &MotionOptions::max_iterations, "[0, 1000000]", "", "RANSAC hypotheses per pass"),
      number("min_iterations", &MotionOptions::min_iterations, "[0, 1000000]", "",
             "RANSAC hypotheses per pass at least"),
      // 1: never stop before max_iterations.
      number("confidence", &MotionOptions::confidence, "[0, 1]", "",
             "stop when the best model is found with this probability"),
      number("inlier_threshold", &MotionOptions::inlier_threshold, "(0, 10]", "m",
             "a candidate pair is an inlier when its lines pass within this distance (paper: 2 cm KITTI, 5 mm TUM)"),
      // The refinement divides by both plane thresholds.
      number("plane_angle_threshold_deg", &MotionOptions::plane_angle_threshold_deg, "(0, 90]", "deg",
             "plane pair inlier: normal angle"),
      number("plane_distance_threshold", &MotionOptions::plane_distance_threshold, "(0, 10]", "m",
             "plane pair inlier: offset difference"),
      number("refine_iterations", &MotionOptions::refine_iterations, "[0, 1000]", "",
             "least-squares iterations on all inliers"),
      number("huber_delta", &MotionOptions::huber_delta, "[0, 10]", "m",
             "robust loss width of the refinement; 0 = inlier threshold"),
      number("degeneracy_threshold", &MotionOptions::degeneracy_threshold, "[0, 1]", "",
             "the refinement is degenerate when its normal matrix (rotations scaled to metres) is worse conditioned "
             "than this"),
  }};
}

// What the odometry sets itself for each pass, and a caller of estimate_motion may choose.
SettingsTable<MotionOptions> motion_pass_settings() {
  return {"estimate_motion option", {
      number("seed", &MotionOptions::seed, ">= 0", "", "random seed of the sampling"),
      number("min_inliers", &MotionOptions::min_inliers, ">= 0", "",
             "success needs at least this many line-pair inliers after the refinement"),
      flag("local_optimisation", &MotionOptions::local_optimisation,
           "refine every new best hypothesis on its inliers (LO-RANSAC)"),
      flag("pretest", &MotionOptions::pretest, "score a random subset first and drop clearly worse hypotheses"),
      number("min_inlier_contrast", &MotionOptions::min_inlier_contrast, "[0, 1e9]", "",
             "success needs an inlier weight of at least this times the chance agreement c plus 3 sqrt(c) (c: the "
             "mean inlier weight of the estimate pushed 20 thresholds 8 generic ways)"),
      choice("solve_7l_method", &MotionOptions::solve_7l_method,
             {{"gauss_newton", Solve7LMethod::kGaussNewton},
              {"alternating_projection", Solve7LMethod::kAlternatingProjection}},
             "the 7L solver: Gauss-Newton on SE(3) over the 7 signed distances, or the paper's alternating "
             "projection (§4)"),
      number("solve_7l_max_iterations", &MotionOptions::solve_7l_max_iterations, ">= 0", "",
             "iterations of the 7L solver (0: its own default for the method)"),
  }};
}

SettingsTable<RegistrationOptions> registration_settings() {
  return {"engine setting", {
      number("passes", &RegistrationOptions::passes, "[1, 10]", "",
             "candidate + RANSAC passes per frame, each seeded with the best estimate so far (paper §6.3: 3)"),
      number("pass_distance_scale", &RegistrationOptions::pass_distance_scale, "[0.01, 1]", "",
             "candidate distance multiplier from one pass to the next (1 = the same threshold every pass)"),
      number("max_lines", &RegistrationOptions::max_lines, "[0, 10000000]", "",
             "lines registered per scan: when more were fitted, only those of every s-th row and column give "
             "normals, planes and the registration, s the smallest step within this budget, and the next scan is "
             "fitted only on the rows and columns that step keeps (each line still fitted to every point of its row "
             "or column; neighbouring rows on one surface give nearly the same intersections). 0 = all"),
      number("window", &RegistrationOptions::window, "[1, 10]", "scans",
             "previous scans each scan is registered against at most: their lines and planes moved into the last "
             "scan's frame by the estimated motions, an older scan taken only while those taken hold fewer than "
             "max_lines lines, the result kept only when the last scan alone observes every direction of it (1 = the "
             "last scan only, paper §6.3)"),
      number("first_motion_pairs_per_line", &RegistrationOptions::first_motion_pairs_per_line, "[0, 100000]", "",
             "while there is no motion guess (the first motion after start or reset, searched from standing still), "
             "keep the k closest partners of each line within candidates.max_distance (0 = all of them, as in the "
             "paper)"),
      number("min_inliers", &RegistrationOptions::min_inliers, "[0, 1000000]", "",
             "fewer inlier pairs than this: registration failed, the motion model's prediction is held"),
      number("max_translation", &RegistrationOptions::max_translation, "[0.001, 1000]", "m",
             "an estimate further than this from the prediction is rejected"),
      number("max_rotation_deg", &RegistrationOptions::max_rotation_deg, "[0.01, 180]", "deg",
             "an estimate rotated more than this from the prediction is rejected"),
      flag("constant_velocity", &RegistrationOptions::constant_velocity,
           "predict each motion from the previous one (scaled by the stamp interval); false = identity"),
      number("persistence_window", &RegistrationOptions::persistence_window, "[0, 100000]", "frames",
             "frames over which the prediction measures, per axis, how much of one frame's estimated motion carries "
             "over to the next (the least-squares a in xi(k+1) ~ a xi(k), clamped to [0, 1]) and carries only that "
             "share: ~1 for a smoothly moving, precisely measured sensor; less where the estimates are noisy against "
             "the motion, so a wrong frame is not extrapolated into the next ones. Constant velocity until 10 pairs. "
             "0 = the last motion as it was"),
      number("max_axis_support", &RegistrationOptions::max_axis_support, "[0, 1]", "",
             "the estimate is degenerate (the prediction is held) when pushing it 20 inlier thresholds along one axis "
             "keeps this share of its inlier weight: that motion is unobservable, e.g. along an endless corridor "
             "(1 = off)"),
      number("max_axis_pair_support", &RegistrationOptions::max_axis_pair_support, "[0, 1]", "",
             "... or when that push keeps this share of the inlier pairs, each pair counted once whatever its "
             "cluster weight (a few coincidental pairs at two planes' seam must not make the corridor's axis look "
             "observed; 1 = off)"),
      number("min_inlier_ratio", &RegistrationOptions::min_inlier_ratio, "[0, 1]", "",
             "the estimate is degenerate (the prediction is held) unless the share of the last pass's candidate line "
             "pairs that meet within the inlier threshold is shown to exceed this (by 2 binomial standard "
             "deviations): otherwise the lines are too noisy to fix the motion (0 = off; docs/RESULTS.md, 'Preset "
             "choices')"),
      number("max_prediction_gap", &RegistrationOptions::max_prediction_gap, "[0.001, 3600]", "s",
             "a stamp gap longer than this drops the velocity: the motion is found afresh as after a reset instead "
             "of extrapolated"),
      number("min_sample_pair_share", &RegistrationOptions::min_sample_pair_share, "[0, 1]", "",
             "a RANSAC sample replaces the refined guess only if it also keeps this share of the guess's inlier "
             "pairs, counted unweighted (a wrong motion can out-weigh the guess on a few small, heavily weighted "
             "normal clusters while losing the others)"),
      number("guess_preference", &RegistrationOptions::guess_preference, "[0, 1]", "",
             "a RANSAC estimate replaces the refined guess (prediction or previous pass) only when its weighted "
             "inlier count is larger by this fraction"),
      number("coarse_downsample", &RegistrationOptions::coarse_downsample, "[0, 64]", "",
             "while there is no velocity (first motion after start or reset), register the scans downsampled by "
             "this step first and start from that estimate (0 or = downsample: off; finer than downsample helps "
             "where the sparse scans barely observe the motion, e.g. a highway at 1/64)"),
      number("covariance_scale", &RegistrationOptions::covariance_scale, "[1e-6, 1e9]", "",
             "multiplies the refinement's covariance before it is reported and fused (the least-squares covariance "
             "ignores wrong candidate pairs)"),
      flag("covariance_per_inlier", &RegistrationOptions::covariance_per_inlier,
           "covariance_scale multiplies the covariance once per inlier constraint, i.e. the frame's error does not "
           "shrink with the number of constraints, as measured on real sensors (their errors are shared: "
           "calibration, surfaces); false: the least-squares 1/n"),
      number("motion_prior_translation_sigma", &RegistrationOptions::motion_prior_translation_sigma, "[0, 100]",
             "m", "1-sigma deviation per frame from the constant-velocity prediction; > 0 fuses the estimate with "
             "the prediction so poorly observed directions follow the motion model (0 = off)"),
      number("motion_prior_rotation_sigma_deg", &RegistrationOptions::motion_prior_rotation_sigma_deg,
             "[1e-6, 180]", "deg", "1-sigma deviation per frame from the constant-velocity prediction, used with "
             "motion_prior_translation_sigma"),
      flag("partial_updates", &RegistrationOptions::partial_updates,
           "a degenerate registration keeps the directions the lines observe and holds only the others at the "
           "prediction (false: holds the whole prediction)"),
      number("fallback_translation_sigma", &RegistrationOptions::fallback_translation_sigma, "[0, 1000]", "m",
             "1-sigma translation uncertainty reported when the prediction is held"),
      number("fallback_rotation_sigma_deg", &RegistrationOptions::fallback_rotation_sigma_deg, "[0, 180]", "deg",
             "1-sigma rotation uncertainty reported when the prediction is held"),
  }};
}

// Point-to-plane refinement (beyond the paper; docs/RESULTS.md, "Preset choices").
SettingsTable<PointRefineOptions> point_settings() {
  return {"engine setting", {
      number("weight", &PointRefineOptions::weight, "[0, 1e6]", "1/m^2",
             "information of one point-to-plane residual of this scan's voxel means against the previous scan's "
             "voxel planes, refined jointly with the lines' estimate (as a Gaussian of its covariance) after the "
             "registration; dense scans only: on sparse ones the voxels' planes are poor. 0 = off (the paper's "
             "method)"),
      number("max_downsample", &PointRefineOptions::max_downsample, "[1, 1000]", "",
             "the refinement runs only while downsample is at most this step (the weight is measured at full "
             "resolution; sparser scans lose with it: docs/RESULTS.md)"),
      number("voxel", &PointRefineOptions::voxel, "[0.01, 10]", "m",
             "both scans are binned in cubes of this size: this scan's voxel means are matched to the planes of the "
             "previous scan's voxels they fall in"),
      number("stride", &PointRefineOptions::stride, "[1, 64]", "",
             "every n-th row and column of the range image is binned"),
      number("min_points", &PointRefineOptions::min_points, "[3, 1000000]", "",
             "points a voxel needs: for its plane (previous scan) and for its mean (this scan)"),
      number("min_planarity", &PointRefineOptions::min_planarity, "[0, 1]", "",
             "a voxel is flat enough when (l1 - l0) / l2 of its points' scatter's eigenvalues reaches this"),
      number("huber", &PointRefineOptions::huber, "(0, 10]", "m",
             "robust loss width of the point-to-plane residuals"),
      number("iterations", &PointRefineOptions::iterations, "[1, 100]", "",
             "Gauss-Newton iterations, the partners found again in each"),
      number("max_translation", &PointRefineOptions::max_translation, "[0, 10]", "m",
             "a refinement moving the lines' estimate further than this is not taken"),
      number("max_rotation_deg", &PointRefineOptions::max_rotation_deg, "[0, 180]", "deg",
             "... or turning it more than this"),
  }};
}

// The local point map, asked where the lines leave a direction of the motion open (beyond the paper; docs/NODE.md,
// "Validation").
SettingsTable<PointMapOptions> point_map_settings() {
  return {"engine setting", {
      flag("enabled", &PointMapOptions::enabled,
           "keep a map of the last scans' points and align a scan to it where the lines do not pin its motion down "
           "(a first motion, a direction validation finds open, a failed registration); false: those hold the "
           "prediction"),
      number("voxel", &PointMapOptions::voxel, "0 (off) or [0.01, 100]", "m",
             "the map's cubes (0: sensor.max_range / 100)"),
      number("max_points_per_voxel", &PointMapOptions::max_points_per_voxel, "[1, 1000]", "", "points a cube keeps"),
      choice("keep", &PointMapOptions::keep, std::vector<std::string>{"viewpoints", "first"},
             "which points of a full cube give way to new ones. viewpoints: those a scan added within "
             "point_map.min_motion of where another scan in the cube stood, the oldest first: while the sensor stands "
             "still its scans sample the cube again the same way, and a sparse scan's rings where it stood would fill "
             "the map and pull each alignment back towards that place once it moves on; first: none, the first points "
             "stay, as KISS-ICP"),
      choice("ground_planes", &PointMapOptions::ground_planes, {"never", "first_motion", "always"},
             "match a cube's points to the ground's plane where they lie within a cube of their scan's ground plane "
             "(its largest plane facing the sensor's z axis) and are one point or run along it, a ring's arc: where a "
             "sparse scan's ring meets the ground is where the sensor put it, and matched point to point the rings "
             "hold a scan at the last one's place. first_motion: in the first motion's alignment, where the map holds "
             "one scan sampled by the same lasers; always: in every alignment; never: point to point, as KISS-ICP"),
      number("max_iterations", &PointMapOptions::alignment, &PointAlignmentOptions::max_iterations, "[1, 1000]", "",
             "Gauss-Newton iterations of an alignment"),
      number("initial_threshold", &PointMapOptions::alignment, &PointAlignmentOptions::initial_threshold,
             "(0, 100]", "m",
             "the motion model's error assumed before one was measured: the alignment's first reach (3 times it)"),
      number("min_motion", &PointMapOptions::alignment, &PointAlignmentOptions::min_motion, "[0, 100]", "m",
             "frames moving less than this do not measure the motion model's error"),
  }};
}

// Whether the lines pin each motion down (beyond the paper; docs/NODE.md, "Validation").
SettingsTable<ObservabilityOptions> validation_settings() {
  return {"engine setting", {
      flag("enabled", &ObservabilityOptions::enabled,
           "test each direction of a registered motion: McNemar's test of the lines meeting under it against those "
           "meeting under it pushed either way; a direction not pinned down is held at the point map's alignment "
           "and the frame flagged"),
      number("tolerance", &ObservabilityOptions::tolerance, "(0, 100]", "m",
             "how far each push moves the lines (rotations: at the lines' rms range): a registered motion is claimed "
             "right to this"),
      number("motion_share", &ObservabilityOptions::motion_share, "[0, 1]", "",
             "... or this share of the motion's translation, when larger"),
      number("significance", &ObservabilityOptions::significance, "(0, 100]", "",
             "z a push must be rejected by for its direction to count as pinned down; and by which a first motion's "
             "points must fit an alignment from a shifted start better than standing still's (or that start better "
             "than its mirror image about standing still), and a frame's points the lines' motion better than their "
             "own alignment on the other side of standing still, for it to confirm the lines' direction; and by which "
             "a frame's points must fit their own alignment better than a turn the lines confirm for the turn to be "
             "contradicted"),
  }};
}

}  // namespace

const SettingsTable<FeatureConfig>& feature_settings() {
  static const SettingsTable<FeatureConfig> table =
      SettingsTable<FeatureConfig>("feature parameter", {})
          .add("lines", &FeatureConfig::lines, line_settings())
          .add("normals", &FeatureConfig::normals, normal_settings())
          .add("planes", &FeatureConfig::planes, plane_settings());
  return table;
}

const SettingsTable<MotionOptions>& motion_settings() {
  static const SettingsTable<MotionOptions> table =
      SettingsTable<MotionOptions>("estimate_motion option", {}).add(ransac_settings()).add(motion_pass_settings());
  return table;
}

const SettingsTable<OdometryConfig>& odometry_settings() {
  static const SettingsTable<OdometryConfig> table =
      SettingsTable<OdometryConfig>("engine setting", {
          number("downsample", &OdometryConfig::downsample, "[1, 64]", "",
                 "keep every n-th row and column of the range image (1 = full resolution, 6 = 1/36, 8 = 1/64, "
                 "10 = 1/100)"),
          // Within a ROS integer parameter (int64).
          number("seed", &OdometryConfig::seed, "[0, 4611686018427387904]", "",
                 "random seed of every sampling step (runs are deterministic for a seed)"),
          number("threads", &OdometryConfig::threads, "[0, 256]", "",
                 "threads of the line fit and the line-pair search (0 = one per hardware thread); the results do "
                 "not depend on it"),
      })
          .add("sensor", &OdometryConfig::sensor, sensor_settings())
          .add("", &OdometryConfig::features, feature_settings())
          .add("candidates", &OdometryConfig::candidates, candidate_settings())
          .add("ransac", &OdometryConfig::ransac, ransac_settings())
          .add("registration", &OdometryConfig::registration, registration_settings())
          .add("points", &OdometryConfig::points, point_settings())
          .add("point_map", &OdometryConfig::point_map, point_map_settings())
          .add("validation", &OdometryConfig::validation, validation_settings());
  return table;
}

}  // namespace line_odom
