// The odometry's configuration: one struct per area, its dotted settings one row each in engine_settings.cpp (the
// ROS parameters and the YAML presets follow from the rows).
#pragma once

#include <cstdint>
#include <string>

#include "features/feature_extraction.hpp"
#include "registration/candidates.hpp"
#include "registration/motion_estimation.hpp"
#include "registration/point_alignment.hpp"
#include "registration/point_refine.hpp"
#include "scan/range_image.hpp"
#include "validation/observability.hpp"

namespace line_odom {

struct RegistrationOptions {
  int passes = 3;                       // paper §6.3
  double pass_distance_scale = 1.0;     // candidate distance multiplier from one pass to the next
  int min_inliers = 12;                 // fewer: failed, hold the prediction
  double max_translation = 5.0;         // reject estimates this far (m) from the prediction
  double max_rotation_deg = 30.0;       // ... or rotated this much from it
  bool constant_velocity = true;        // false: predict identity
  int persistence_window = 0;           // frames: the prediction scales the last motion per axis by its measured
                                        // persistence (motion_persistence.hpp); 0: the last motion as it was
  double max_axis_support = 0.97;       // degenerate when a push along one axis keeps this share of the inliers
  double max_axis_pair_support = 0.995;  // ... or this share of the inlier pairs, each counted once
  double min_inlier_ratio = 0.3;        // degenerate when fewer of the last pass's candidate pairs are inliers
  double max_prediction_gap = 1.0;      // s; a longer stamp gap drops the velocity (start as after a reset)
  double min_sample_pair_share = 0.95;  // ... and keep at least this share of its inlier pairs (unweighted)
  double guess_preference = 0.0;        // the RANSAC winner must beat the refined guess's weighted inliers by
                                        // this fraction to replace it
  double covariance_scale = 1.0;        // multiplies the refinement's covariance (it ignores candidate errors)
  bool covariance_per_inlier = false;   // ... once per inlier constraint: sigma^2 (H / n)^-1, a frame's error that
                                        // does not shrink with the number of constraints (docs/RESULTS.md)
  double motion_prior_translation_sigma = 0.0;  // constant-velocity prior per frame (m); 0: no fusion
  double motion_prior_rotation_sigma_deg = 0.5;
  int max_lines = 3000;                 // lines registered per scan: past this, those of every s-th row and column
                                        // (line_selection.hpp); 0: all
  int window = 1;                       // previous scans registered against (feature_window.hpp); 1: the last one
  int first_motion_pairs_per_line = 0;  // no motion guess yet: the k closest partners of each line (0: all within
                                        // candidates.max_distance, paper §6.3)
  int coarse_downsample = 6;            // no velocity yet: register at this step first (0 / = downsample: off)
  bool partial_updates = true;          // degenerate: keep what the pairs observe, hold only the rest (refine.hpp)
  double fallback_translation_sigma = 0.5;    // covariance reported when the prediction is held
  double fallback_rotation_sigma_deg = 5.0;
};

// Which SensorModel organizes unorganized clouds: a preset ("hdl64", "vlp16", "os128"), or "uniform" with
// rows beams evenly spaced between max/min elevation. cols > 0 overrides the preset's azimuth bins.
struct SensorOptions {
  std::string model = "hdl64";
  int rows = 0;
  int cols = 0;
  double max_elevation_deg = 2.0;
  double min_elevation_deg = -24.9;
  RangeLimits limits;
  bool deskew = true;              // points with times: moved into the frame at the stamp (deskew.hpp)
  double deskew_tolerance = 0.005;  // m: the previous scan is deskewed again when the velocity changed by more
  int deskew_trend = 3;             // frames: a sweep is corrected at the pair's velocity plus the change from the
                                    // previous sweep's, the slope of the last n registered velocities (0: off)
  int deskew_iterations = 1;        // a sweep with times before its stamp (stamped at its end) is deskewed again at the
                                    // motion registered for it, when that differs by more than deskew_tolerance, and
                                    // registered again, at most this many times; 0: at the prediction only
};

// The SensorModel the options describe; throws std::invalid_argument when they are inconsistent.
SensorModel make_sensor_model(const SensorOptions& options);

// point_map.*: the local map of the last scans' points and the alignment to it (voxel_points.hpp,
// point_alignment.hpp), asked where the lines leave a direction of the motion open.
struct PointMapOptions {
  bool enabled = true;
  double voxel = 0.0;              // m: the map's cubes; 0: sensor.max_range / 100 (KISS-ICP's resolution)
  int max_points_per_voxel = 20;
  // Which points of a full cube give way to new ones: "viewpoints" (those from where another scan in it stood, within
  // alignment.min_motion) or "first" (none: the first stay).
  std::string keep = "viewpoints";
  // Points on the scan's ground plane matched to the ground's plane (VoxelPointMap::plane): "never", "first_motion"
  // (in the first motion's alignment: PointMapTracker) or "always".
  std::string ground_planes = "always";
  PointAlignmentOptions alignment;
};

struct OdometryConfig {
  int downsample = 1;  // keep every n-th row and column (paper §6.1)
  std::uint64_t seed = 0;
  int threads = 1;  // of the line fit and the line-pair search (worker_pool.hpp); 0: one per hardware thread. Same
                    // results.
  SensorOptions sensor;
  FeatureConfig features;  // lines.*, normals.*, planes.*
  CandidateOptions candidates;
  MotionOptions ransac;
  RegistrationOptions registration;
  PointRefineOptions points;     // points.*: the point-to-plane refinement (point_refine.hpp)
  PointMapOptions point_map;     // point_map.*
  ObservabilityOptions validation;  // validation.*: whether the lines pin each motion down (observability.hpp)
};

}  // namespace line_odom
